//! Decoding indexed messages by their topic's role: the channel's encoding and schema are
//! checked against the role, then the payload is loaded and decoded from CDR.
//!
//! Invariants: a topic without a role is never loaded (its payload may be anything); the
//! checks run in the same order as before payloads were loaded lazily, so a message fails
//! with the same error.

use super::super::{Frame, FramePixels, Role, SessionError, SessionMsg, TimedMsg};
use super::{ChannelInfo, MessageMeta, SessionReader, normalize_type};
use crate::io::msgs::{
    CameraInfo, CompressedImage, GroundTruth, Image, ObjectLabel, Odometry, PoseStamped,
    RosMessage, TfMessage, TwistStamped,
};

impl SessionReader {
    /// The channel of `meta`; present for every message (checked when indexed).
    fn channel(&self, meta: &MessageMeta) -> Result<&ChannelInfo, SessionError> {
        self.channels
            .get(&meta.channel_id)
            .ok_or_else(|| SessionError::Invalid {
                at: self.at(None, meta.log_time_ns),
                what: format!("unknown channel {}", meta.channel_id),
            })
    }

    /// The role of a channel's topic, after checking its encoding and schema fit that role.
    pub fn channel_role(
        &self,
        channel: &ChannelInfo,
        log_time_ns: u64,
    ) -> Result<Option<Role>, SessionError> {
        let Some(role) = self.topics.role_of(&channel.topic) else {
            return Ok(None);
        };
        let at = || self.at(Some(&channel.topic), log_time_ns);
        if channel.message_encoding != "cdr" {
            return Err(SessionError::Encoding {
                at: at(),
                found: channel.message_encoding.clone(),
            });
        }
        if channel.schema_encoding != "ros2msg" {
            return Err(SessionError::SchemaEncoding {
                at: at(),
                found: channel.schema_encoding.clone(),
            });
        }
        if normalize_type(&channel.schema_name) != role.message_type() {
            return Err(SessionError::WrongType {
                at: at(),
                expected: role.message_type(),
                found: channel.schema_name.clone(),
            });
        }
        Ok(Some(role))
    }

    /// Decodes one message, loading its payload; `Ok(None)` for topics that play no role in
    /// a session (their payload is not read).
    pub fn decode(&self, meta: &MessageMeta) -> Result<Option<TimedMsg>, SessionError> {
        let channel = self.channel(meta)?;
        let Some(role) = self.channel_role(channel, meta.log_time_ns)? else {
            return Ok(None);
        };
        let msg = self
            .with_payload(meta, |d| decode_cdr(role, d))?
            .map_err(|source| SessionError::Decode {
                at: self.at(Some(&channel.topic), meta.log_time_ns),
                type_name: role.message_type().to_owned(),
                source,
            })?;
        // Boxes that cannot be scored against are refused here, not scored as nothing (a NaN
        // box matched no object, and eval reported the chair as spurious with exit 0).
        if let SessionMsg::GroundTruthObjects(g) = &msg
            && let Some(what) = g.problem()
        {
            return Err(SessionError::Invalid {
                at: self.at(Some(&channel.topic), meta.log_time_ns),
                what,
            });
        }
        Ok(Some(TimedMsg {
            log_time_ns: meta.log_time_ns,
            topic: channel.topic.clone(),
            msg,
        }))
    }

    /// Every message with a role, decoded, in replay order; payloads are loaded one at a
    /// time, as the iterator is advanced.
    pub fn messages(&self) -> impl Iterator<Item = Result<TimedMsg, SessionError>> + '_ {
        self.ordered()
            .filter_map(|meta| meta.and_then(|m| self.decode(&m)).transpose())
    }
}

/// The payload `d` decoded as the type of `role`.
fn decode_cdr(role: Role, d: &[u8]) -> Result<SessionMsg, crate::io::cdr::CdrError> {
    Ok(match role {
        Role::CompressedImage => {
            let m = CompressedImage::from_cdr(d)?;
            SessionMsg::Frame(Frame {
                stamp_ns: m.header.stamp_ns,
                frame_id: m.header.frame_id,
                pixels: FramePixels::Encoded {
                    format: m.format,
                    data: m.data,
                },
            })
        }
        Role::Image => {
            let m = Image::from_cdr(d)?;
            SessionMsg::Frame(Frame {
                stamp_ns: m.header.stamp_ns,
                frame_id: m.header.frame_id.clone(),
                pixels: FramePixels::Raw(m),
            })
        }
        Role::CameraInfo => SessionMsg::CameraInfo(Box::new(CameraInfo::from_cdr(d)?)),
        Role::TfStatic => SessionMsg::TfStatic(TfMessage::from_cdr(d)?),
        Role::Tf => SessionMsg::Tf(TfMessage::from_cdr(d)?),
        Role::Odom => SessionMsg::Odom(Box::new(Odometry::from_cdr(d)?)),
        Role::CmdVel => SessionMsg::CmdVel(TwistStamped::from_cdr(d)?),
        Role::Labels => SessionMsg::Label(ObjectLabel::from_cdr(d)?),
        Role::GroundTruthPose => SessionMsg::GroundTruthPose(PoseStamped::from_cdr(d)?),
        Role::GroundTruthObjects => SessionMsg::GroundTruthObjects(GroundTruth::from_cdr(d)?),
    })
}
