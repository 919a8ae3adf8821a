//! Hex digests: the one hex encoding of the code base, and SHA-256 of bytes.
//!
//! Invariants: lower-case hex, two digits per byte.

use sha2::{Digest, Sha256};

/// Lower-case hex of `bytes`.
pub fn hex(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        s.push(char::from(DIGITS[usize::from(b >> 4)]));
        s.push(char::from(DIGITS[usize::from(b & 15)]));
    }
    s
}

/// Hex SHA-256 of everything `reader` yields, read in 1 MiB blocks: a session file of any
/// size is hashed without being held in memory.
pub fn sha256_hex_of_reader(mut reader: impl std::io::Read) -> std::io::Result<String> {
    let mut hasher = Sha256::new();
    let mut block = vec![0u8; 1 << 20];
    loop {
        let n = match reader.read(&mut block) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        hasher.update(&block[..n]);
    }
    Ok(hex(&hasher.finalize()))
}

/// Hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_blockwise_hash_is_the_hash_of_the_bytes() {
        // Over two blocks and a part, so block boundaries are crossed.
        let bytes: Vec<u8> = (0..(5u32 << 19)).map(|i| (i * 7 + i / 251) as u8).collect();
        assert_eq!(
            sha256_hex_of_reader(&bytes[..]).unwrap(),
            sha256_hex(&bytes)
        );
    }

    #[test]
    fn hex_and_the_sha256_of_abc() {
        assert_eq!(hex(&[0x00, 0x0f, 0xa5, 0xff]), "000fa5ff");
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }
}
