//! TensorBoard event files, written from the format's definition: a file of TFRecords (length,
//! masked CRC-32C of the length, data, masked CRC-32C of the data), each holding one `Event`
//! protocol buffer. Only what scalars need is encoded: `Event { wall_time, step, file_version |
//! summary { value { tag, simple_value } } | session_log { status } }`.
//!
//! A resumed run writes a new file in the same directory that starts with `SessionLog.START` at
//! the step it resumes from: TensorBoard then drops what the stopped run had written past it.

use anyhow::{Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};

/// CRC-32C (Castagnoli), the checksum TFRecord uses; bitwise, reflected polynomial 0x82F63B78.
pub fn crc32c(data: &[u8]) -> u32 {
    static TABLE: std::sync::OnceLock<[u32; 256]> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let mut t = [0u32; 256];
        for (i, e) in t.iter_mut().enumerate() {
            let mut c = i as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    (c >> 1) ^ 0x82F6_3B78
                } else {
                    c >> 1
                };
            }
            *e = c;
        }
        t
    });
    !data.iter().fold(!0u32, |c, &b| {
        table[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8)
    })
}

/// TFRecord's masking of a CRC (so that CRCs of data holding CRCs stay well distributed).
fn masked(crc: u32) -> u32 {
    crc.rotate_right(15).wrapping_add(0xa282_ead8)
}

/// One TFRecord around `data`.
fn record(data: &[u8]) -> Vec<u8> {
    let len = (data.len() as u64).to_le_bytes();
    let mut r = Vec::with_capacity(data.len() + 16);
    r.extend_from_slice(&len);
    r.extend_from_slice(&masked(crc32c(&len)).to_le_bytes());
    r.extend_from_slice(data);
    r.extend_from_slice(&masked(crc32c(data)).to_le_bytes());
    r
}

// Protocol-buffer wire format: a key is (field number << 3) | wire type.
fn varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}
fn field_bytes(out: &mut Vec<u8>, field: u64, bytes: &[u8]) {
    varint(out, (field << 3) | 2);
    varint(out, bytes.len() as u64);
    out.extend_from_slice(bytes);
}

/// `Event { wall_time = 1, step = 2, <what> }`, where `what` is already a field of `Event`.
fn event(wall_time: f64, step: u64, what: &[u8]) -> Vec<u8> {
    let mut e = Vec::with_capacity(what.len() + 16);
    varint(&mut e, (1 << 3) | 1);
    e.extend_from_slice(&wall_time.to_le_bytes());
    varint(&mut e, 2 << 3);
    varint(&mut e, step);
    e.extend_from_slice(what);
    e
}

/// Writes scalars to `DIR/events.out.tfevents.<time>.<host>.<pid>`.
pub struct EventWriter {
    file: std::io::BufWriter<std::fs::File>,
    path: PathBuf,
}

impl EventWriter {
    /// A new event file in `dir`; its first events are the file version and `SessionLog.START`
    /// at `step` (0 for a new run, the resumed step for a resumed one).
    pub fn create(dir: &Path, step: u64) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let now = wall_time();
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
            .map(|h| h.trim().to_string())
            .unwrap_or_else(|_| "localhost".into());
        let path = dir.join(format!(
            "events.out.tfevents.{}.{host}.{}",
            now as u64,
            std::process::id()
        ));
        let file =
            std::fs::File::create(&path).with_context(|| format!("creating {}", path.display()))?;
        let mut w = Self {
            file: std::io::BufWriter::new(file),
            path,
        };
        let mut version = Vec::new();
        field_bytes(&mut version, 3, b"brain.Event:2");
        w.write(&event(now, 0, &version))?;
        // session_log = 6 { status = 1: START }
        let mut start = Vec::new();
        field_bytes(&mut start, 6, &[1 << 3, 1]);
        w.write(&event(now, step, &start))?;
        w.flush()?;
        Ok(w)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// One scalar at `step`; non-finite values are skipped (TensorBoard would draw them as gaps
    /// or spikes, and metrics.csv keeps them).
    pub fn scalar(&mut self, tag: &str, step: u64, value: f64) -> Result<()> {
        if !value.is_finite() {
            return Ok(());
        }
        // summary = 5 { value = 1 { tag = 1, simple_value = 2 (float) } }
        let mut v = Vec::new();
        field_bytes(&mut v, 1, tag.as_bytes());
        varint(&mut v, (2 << 3) | 5);
        v.extend_from_slice(&(value as f32).to_le_bytes());
        let mut summary = Vec::new();
        field_bytes(&mut summary, 1, &v);
        let mut what = Vec::new();
        field_bytes(&mut what, 5, &summary);
        self.write(&event(wall_time(), step, &what))
    }

    fn write(&mut self, event: &[u8]) -> Result<()> {
        self.file
            .write_all(&record(event))
            .with_context(|| format!("writing {}", self.path.display()))
    }

    pub fn flush(&mut self) -> Result<()> {
        self.file
            .flush()
            .with_context(|| format!("writing {}", self.path.display()))
    }
}

fn wall_time() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc32c_matches_published_check_values() {
        // The standard check value, and RFC 3720's (iSCSI) test patterns, appendix B.4.
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(crc32c(&[0xffu8; 32]), 0x62A8_AB43);
        let ascending: Vec<u8> = (0..32).collect();
        assert_eq!(crc32c(&ascending), 0x46DD_794E);
    }

    #[test]
    fn records_frame_their_data_with_masked_checksums() {
        let r = record(b"abc");
        assert_eq!(r.len(), 8 + 4 + 3 + 4);
        assert_eq!(u64::from_le_bytes(r[..8].try_into().unwrap()), 3);
        assert_eq!(&r[12..15], b"abc");
        // The mask, by its definition: rotate right by 15, add 0xa282ead8.
        let crc = crc32c(b"abc");
        let want = ((crc >> 15) | (crc << 17)).wrapping_add(0xa282_ead8);
        assert_eq!(u32::from_le_bytes(r[15..19].try_into().unwrap()), want);
    }

    #[test]
    fn varints_are_little_endian_groups_of_seven_bits() {
        let enc = |v| {
            let mut o = Vec::new();
            varint(&mut o, v);
            o
        };
        assert_eq!(enc(1), [1]);
        assert_eq!(enc(300), [0xAC, 0x02]);
        assert_eq!(enc(u64::MAX).len(), 10);
    }
}
