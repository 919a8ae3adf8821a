//! The semi-holonomic robot (like the paper's B21): it either rotates in place or drives
//! straight, one command at a time, each held for a whole number of milliseconds.
//!
//! Invariants: the nominal (odometry) pose integrates exactly the commanded twist over the
//! command's duration; the true pose integrates the same twist scaled by one Gaussian factor
//! per command (`1 + sigma * N(0, 1)`), and nothing else, so the fuser's motion model is
//! exactly right. All randomness comes from a seeded [`Rng`]; the timeline is a pure function
//! of (stops, speeds, noise, seed).

use crate::types::geometry::wrap_angle;

/// Pause between one command's end and the next command's start.
pub const SETTLE_NS: i64 = 300_000_000;
/// A frame is taken this long after the robot stops, and the next command starts this long
/// after the frame.
pub const FRAME_GAP_NS: i64 = 500_000_000;
/// Odometry rate while moving.
pub const ODOM_PERIOD_NS: i64 = 100_000_000;

/// The simulator's generator: seeded, identical on every platform.
pub use crate::types::rng::SplitMix64 as Rng;

/// A planar pose in odom: metres and radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose2 {
    /// Position along `odom` x, metres.
    pub x_m: f64,
    /// Position along `odom` y, metres.
    pub y_m: f64,
    /// Heading about z, counter-clockwise from `odom` +x, radians in (-pi, pi].
    pub yaw_rad: f64,
}

/// Relative standard deviations of the executed speeds, and a systematic turn error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedNoise {
    /// Relative standard deviation of a drive command's executed speed (0.01 = 1 %).
    pub trans_rel_sigma: f64,
    /// Relative standard deviation of a rotate command's executed turn rate.
    pub rot_rel_sigma: f64,
    /// The robot turns by (1 + this) times what odometry reports, on every rotation (a
    /// miscalibrated wheel base): a known heading bias to test pose correction against.
    pub rot_rel_bias: f64,
}

impl Default for SpeedNoise {
    fn default() -> Self {
        Self {
            trans_rel_sigma: 0.01,
            rot_rel_sigma: 0.006,
            rot_rel_bias: 0.0,
        }
    }
}

/// Where the robot stops to take a frame; `background` frames are rendered without the target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stop {
    /// Where the robot stands for the frame, planned, in `odom`.
    pub pose: Pose2,
    /// Whether the frame is rendered without the target (train sessions).
    pub background: bool,
}

/// Something that happens at `stamp_ns` (all timeline events are in time order).
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// A command starts (non-zero twist) or ends (zero twist).
    CmdVel {
        /// When the command starts or ends, ns since the Unix epoch.
        stamp_ns: i64,
        /// Commanded forward speed, m/s.
        linear_m_s: f64,
        /// Commanded turn rate, rad/s, counter-clockwise.
        angular_rad_s: f64,
    },
    /// Odometry (nominal) and ground-truth poses at the same stamp, with the nominal twist.
    Pose {
        /// Stamp of both poses, ns since the Unix epoch.
        stamp_ns: i64,
        /// The odometry pose: the commanded twist integrated.
        nominal: Pose2,
        /// The true pose: the executed (noisy) twist integrated.
        truth: Pose2,
        /// Commanded forward speed at the stamp, m/s.
        linear_m_s: f64,
        /// Commanded turn rate at the stamp, rad/s.
        angular_rad_s: f64,
    },
    /// The robot is still; take frame `index` (into the stops).
    Frame {
        /// When the frame is taken, ns since the Unix epoch.
        stamp_ns: i64,
        /// Index of the stop, and so of the frame.
        index: usize,
        /// Whether the frame is rendered without the target.
        background: bool,
        /// The odometry pose at the frame.
        nominal: Pose2,
        /// The true pose, which the frame is rendered from.
        truth: Pose2,
    },
}

impl Event {
    /// When the event happens, ns since the Unix epoch.
    pub fn stamp_ns(&self) -> i64 {
        match self {
            Event::CmdVel { stamp_ns, .. }
            | Event::Pose { stamp_ns, .. }
            | Event::Frame { stamp_ns, .. } => *stamp_ns,
        }
    }
}

/// One motion command: the robot either rotates in place or drives straight.
#[derive(Debug, Clone, Copy)]
enum Command {
    Rotate { angle_rad: f64 },
    Drive { distance_m: f64 },
}

/// The robot's speeds and how far the executed ones stray from them.
#[derive(Debug, Clone, Copy)]
struct Motion {
    drive_speed_m_s: f64,
    turn_speed_rad_s: f64,
    noise: SpeedNoise,
}

/// A planar twist: forward and yaw speed.
#[derive(Debug, Clone, Copy)]
struct Twist2 {
    linear_m_s: f64,
    angular_rad_s: f64,
}

impl Twist2 {
    const ZERO: Twist2 = Twist2 {
        linear_m_s: 0.0,
        angular_rad_s: 0.0,
    };

    /// Where `p` gets to after `dt_ns` of this twist scaled by `scale` (the robot only
    /// rotates or drives straight, so one step is exact).
    fn advance(&self, p: Pose2, dt_ns: i64, scale: f64) -> Pose2 {
        let (lin, ang) = (self.linear_m_s, self.angular_rad_s);
        let dt = dt_ns as f64 * 1e-9;
        Pose2 {
            x_m: p.x_m + lin * scale * dt * p.yaw_rad.cos(),
            y_m: p.y_m + lin * scale * dt * p.yaw_rad.sin(),
            yaw_rad: wrap_angle(p.yaw_rad + ang * scale * dt),
        }
    }
}

/// The events so far, and the robot's poses (odometry and truth) and the time at their end.
struct Timeline {
    events: Vec<Event>,
    nominal: Pose2,
    truth: Pose2,
    t_ns: i64,
}

/// Simulates the robot from `stops[0]` (where it starts, odometry = truth) through every
/// stop, taking one frame at each. Returns the events in time order.
pub fn simulate(
    stops: &[Stop],
    start_ns: i64,
    drive_speed_m_s: f64,
    turn_speed_rad_s: f64,
    noise: SpeedNoise,
    rng: &mut Rng,
) -> Vec<Event> {
    let Some(first) = stops.first() else {
        return Vec::new();
    };
    let motion = Motion {
        drive_speed_m_s,
        turn_speed_rad_s,
        noise,
    };
    let mut timeline = Timeline {
        events: Vec::new(),
        nominal: first.pose,
        truth: first.pose,
        t_ns: start_ns,
    };
    timeline.push_pose(Twist2::ZERO);
    timeline.t_ns += 2 * FRAME_GAP_NS;
    for (index, stop) in stops.iter().enumerate() {
        if index > 0 {
            for c in plan(&timeline.nominal, &stop.pose) {
                timeline.execute(c, &motion, rng);
            }
            timeline.t_ns += FRAME_GAP_NS - SETTLE_NS;
        }
        timeline.events.push(Event::Frame {
            stamp_ns: timeline.t_ns,
            index,
            background: stop.background,
            nominal: timeline.nominal,
            truth: timeline.truth,
        });
        timeline.t_ns += FRAME_GAP_NS;
    }
    timeline.events
}

/// The commands from `from` (where odometry believes the robot is) to `to`: rotate to face
/// it and drive there (unless already there), then rotate to its yaw.
fn plan(from: &Pose2, to: &Pose2) -> Vec<Command> {
    let dx = to.x_m - from.x_m;
    let dy = to.y_m - from.y_m;
    let dist = dx.hypot(dy);
    let mut commands = Vec::new();
    let mut heading = from.yaw_rad;
    if dist > 1e-3 {
        let bearing = dy.atan2(dx);
        commands.push(Command::Rotate {
            angle_rad: wrap_angle(bearing - heading),
        });
        commands.push(Command::Drive { distance_m: dist });
        heading = bearing;
    }
    commands.push(Command::Rotate {
        angle_rad: wrap_angle(to.yaw_rad - heading),
    });
    commands
}

impl Timeline {
    /// Appends one command: its start, odometry while it runs, its end and the pause after.
    /// A command shorter than a millisecond is skipped (and takes no random draw).
    fn execute(&mut self, c: Command, motion: &Motion, rng: &mut Rng) {
        let noise = motion.noise;
        let (amount, speed, sigma, bias) = match c {
            Command::Rotate { angle_rad } => (
                angle_rad,
                motion.turn_speed_rad_s,
                noise.rot_rel_sigma,
                noise.rot_rel_bias,
            ),
            Command::Drive { distance_m } => (
                distance_m,
                motion.drive_speed_m_s,
                noise.trans_rel_sigma,
                0.0,
            ),
        };
        let duration_ms = (amount.abs() / speed * 1000.0).ceil();
        if duration_ms < 1.0 {
            return;
        }
        let duration_ns = duration_ms as i64 * 1_000_000;
        // Nominal speed reaches the planned amount exactly in whole milliseconds.
        let nominal_speed = amount / (duration_ms / 1000.0);
        // Bias 0 leaves the factor, and so every shipped session, as it was.
        let factor = 1.0 + sigma * rng.normal() + bias;
        let twist = match c {
            Command::Rotate { .. } => Twist2 {
                linear_m_s: 0.0,
                angular_rad_s: nominal_speed,
            },
            Command::Drive { .. } => Twist2 {
                linear_m_s: nominal_speed,
                angular_rad_s: 0.0,
            },
        };
        let (n0, t0, start) = (self.nominal, self.truth, self.t_ns);
        self.push_cmd_vel(twist);
        self.push_pose(twist);
        let mut k = 1;
        while k * ODOM_PERIOD_NS < duration_ns {
            let dt = k * ODOM_PERIOD_NS;
            self.events.push(Event::Pose {
                stamp_ns: start + dt,
                nominal: twist.advance(n0, dt, 1.0),
                truth: twist.advance(t0, dt, factor),
                linear_m_s: twist.linear_m_s,
                angular_rad_s: twist.angular_rad_s,
            });
            k += 1;
        }
        self.nominal = twist.advance(n0, duration_ns, 1.0);
        self.truth = twist.advance(t0, duration_ns, factor);
        self.t_ns = start + duration_ns;
        self.push_cmd_vel(Twist2::ZERO);
        self.push_pose(Twist2::ZERO);
        self.t_ns += SETTLE_NS;
    }

    /// Appends a /cmd_vel of `twist` at the current time.
    fn push_cmd_vel(&mut self, twist: Twist2) {
        self.events.push(Event::CmdVel {
            stamp_ns: self.t_ns,
            linear_m_s: twist.linear_m_s,
            angular_rad_s: twist.angular_rad_s,
        });
    }

    /// Appends the current poses, moving at `twist`.
    fn push_pose(&mut self, twist: Twist2) {
        self.events.push(Event::Pose {
            stamp_ns: self.t_ns,
            nominal: self.nominal,
            truth: self.truth,
            linear_m_s: twist.linear_m_s,
            angular_rad_s: twist.angular_rad_s,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn stop(x: f64, y: f64, yaw: f64) -> Stop {
        Stop {
            pose: Pose2 {
                x_m: x,
                y_m: y,
                yaw_rad: yaw,
            },
            background: false,
        }
    }

    #[test]
    fn noiseless_run_reaches_each_stop_with_rotate_drive_rotate() {
        let stops = [stop(0.0, 0.0, 0.0), stop(0.0, 0.6, PI)];
        let noise = SpeedNoise {
            trans_rel_sigma: 0.0,
            rot_rel_sigma: 0.0,
            rot_rel_bias: 0.0,
        };
        let ev = simulate(&stops, 1_000_000_000, 0.3, 0.5, noise, &mut Rng::new(1));
        let cmds: Vec<(i64, f64, f64)> = ev
            .iter()
            .filter_map(|e| match e {
                Event::CmdVel {
                    stamp_ns,
                    linear_m_s,
                    angular_rad_s,
                } => Some((*stamp_ns, *linear_m_s, *angular_rad_s)),
                _ => None,
            })
            .collect();
        // Rotate +90 deg: ceil(pi/2 / 0.5 s) = 3142 ms; drive 0.6 m at 0.3 = 2000 ms; rotate +90.
        assert_eq!(cmds.len(), 6);
        let first_frame = 1_000_000_000 + 1_000_000_000;
        let c0 = first_frame + FRAME_GAP_NS;
        assert_eq!(cmds[0].0, c0);
        assert!((cmds[0].2 - (PI / 2.0) * 1000.0 / 3142.0).abs() < 1e-12);
        assert_eq!(cmds[1], (c0 + 3_142_000_000, 0.0, 0.0));
        let c2 = c0 + 3_142_000_000 + SETTLE_NS;
        assert_eq!(cmds[2].0, c2);
        assert!((cmds[2].1 - 0.3).abs() < 1e-12 && cmds[2].2 == 0.0);
        let Some(Event::Frame {
            nominal,
            truth,
            stamp_ns,
            ..
        }) = ev.last()
        else {
            panic!("last event is not a frame")
        };
        assert!(nominal.x_m.abs() < 1e-12 && (nominal.y_m - 0.6).abs() < 1e-12);
        assert!((wrap_angle(nominal.yaw_rad - PI)).abs() < 1e-12);
        assert_eq!(nominal, truth);
        // last rotate ends at c2 + 2000 ms + settle + 3142 ms; frame FRAME_GAP after.
        assert_eq!(
            *stamp_ns,
            c2 + 2_000_000_000 + SETTLE_NS + 3_142_000_000 + FRAME_GAP_NS
        );
        // Time never goes backwards.
        assert!(ev.windows(2).all(|w| w[0].stamp_ns() <= w[1].stamp_ns()));
    }

    #[test]
    fn truth_differs_by_the_speed_factor_only() {
        let stops = [stop(0.0, 0.0, 0.0), stop(2.0, 0.0, 0.0)];
        let noise = SpeedNoise {
            trans_rel_sigma: 0.05,
            rot_rel_sigma: 0.0,
            rot_rel_bias: 0.0,
        };
        let ev = simulate(&stops, 0, 0.25, 0.5, noise, &mut Rng::new(9));
        let mut rng = Rng::new(9);
        // Straight ahead: no rotation commands take a draw before the drive... except the
        // zero-angle rotations, which are skipped before drawing.
        let factor = 1.0 + 0.05 * rng.normal();
        let Some(Event::Frame { nominal, truth, .. }) = ev.last() else {
            panic!()
        };
        assert!((nominal.x_m - 2.0).abs() < 1e-12);
        assert!(
            (truth.x_m - 2.0 * factor).abs() < 1e-12,
            "{} {factor}",
            truth.x_m
        );
    }

    /// A turn bias of 10 %: a commanded quarter turn ends 0.1 * pi/2 further round, with
    /// odometry still at the quarter turn.
    #[test]
    fn turn_bias_scales_every_rotation() {
        let stops = [stop(0.0, 0.0, 0.0), stop(0.0, 0.0, PI / 2.0)];
        let noise = SpeedNoise {
            trans_rel_sigma: 0.0,
            rot_rel_sigma: 0.0,
            rot_rel_bias: 0.1,
        };
        let ev = simulate(&stops, 0, 0.25, 0.5, noise, &mut Rng::new(3));
        let Some(Event::Frame { nominal, truth, .. }) = ev.last() else {
            panic!()
        };
        assert!((nominal.yaw_rad - PI / 2.0).abs() < 1e-12);
        assert!(
            (truth.yaw_rad - 1.1 * PI / 2.0).abs() < 1e-12,
            "{}",
            truth.yaw_rad
        );
    }

    #[test]
    fn wrap() {
        assert!((wrap_angle(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-12);
        assert!((wrap_angle(-PI) - PI).abs() < 1e-12);
    }
}
