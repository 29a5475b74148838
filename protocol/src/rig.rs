//! Fixed binary datagrams for UDP peers that may be written in C on a real-time target:
//! the rig (valve command out, sensors in) and a haptic-device host (operator input in).
//!
//! All fields little-endian, no padding:
//!
//! | datagram | bytes | layout |
//! |---|---|---|
//! | controller → rig | 16 | `"BDFC"`, seq u32, valve command f64 |
//! | rig → controller | 24 | `"BDFR"`, seq u32 (of the command it answers), cylinder position mm f64, cab acceleration mm/s² f64 |
//! | input host → controller | 20 | `"BDFI"`, channel u32, seq u32, hand position mm f64 |

use thiserror::Error;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigCommand {
    pub seq: u32,
    pub valve: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigState {
    pub seq: u32,
    pub cylinder_mm: f64,
    pub cab_accel_mm_s2: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputDatagram {
    pub channel: u32,
    pub seq: u32,
    pub position_mm: f64,
}

#[derive(Debug, Error, PartialEq)]
pub enum DatagramError {
    #[error("datagram of {got} bytes, expected {want}")]
    Size { got: usize, want: usize },
    #[error("wrong magic {0:?}")]
    Magic([u8; 4]),
    #[error("non-finite value")]
    NonFinite,
}

const COMMAND_MAGIC: &[u8; 4] = b"BDFC";
const STATE_MAGIC: &[u8; 4] = b"BDFR";
const INPUT_MAGIC: &[u8; 4] = b"BDFI";

fn header(buf: &[u8], magic: &[u8; 4], want: usize) -> Result<(), DatagramError> {
    if buf.len() != want {
        return Err(DatagramError::Size {
            got: buf.len(),
            want,
        });
    }
    if &buf[..4] != magic {
        return Err(DatagramError::Magic(
            buf[..4].try_into().unwrap_or_default(),
        ));
    }
    Ok(())
}

fn u32_at(buf: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(buf[at..at + 4].try_into().expect("4 bytes"))
}

fn f64_at(buf: &[u8], at: usize) -> Result<f64, DatagramError> {
    let v = f64::from_le_bytes(buf[at..at + 8].try_into().expect("8 bytes"));
    if v.is_finite() {
        Ok(v)
    } else {
        Err(DatagramError::NonFinite)
    }
}

impl RigCommand {
    pub const SIZE: usize = 16;
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut b = [0; Self::SIZE];
        b[..4].copy_from_slice(COMMAND_MAGIC);
        b[4..8].copy_from_slice(&self.seq.to_le_bytes());
        b[8..16].copy_from_slice(&self.valve.to_le_bytes());
        b
    }
    pub fn decode(buf: &[u8]) -> Result<Self, DatagramError> {
        header(buf, COMMAND_MAGIC, Self::SIZE)?;
        Ok(Self {
            seq: u32_at(buf, 4),
            valve: f64_at(buf, 8)?,
        })
    }
}

impl RigState {
    pub const SIZE: usize = 24;
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut b = [0; Self::SIZE];
        b[..4].copy_from_slice(STATE_MAGIC);
        b[4..8].copy_from_slice(&self.seq.to_le_bytes());
        b[8..16].copy_from_slice(&self.cylinder_mm.to_le_bytes());
        b[16..24].copy_from_slice(&self.cab_accel_mm_s2.to_le_bytes());
        b
    }
    pub fn decode(buf: &[u8]) -> Result<Self, DatagramError> {
        header(buf, STATE_MAGIC, Self::SIZE)?;
        Ok(Self {
            seq: u32_at(buf, 4),
            cylinder_mm: f64_at(buf, 8)?,
            cab_accel_mm_s2: f64_at(buf, 16)?,
        })
    }
}

impl InputDatagram {
    pub const SIZE: usize = 20;
    pub fn encode(&self) -> [u8; Self::SIZE] {
        let mut b = [0; Self::SIZE];
        b[..4].copy_from_slice(INPUT_MAGIC);
        b[4..8].copy_from_slice(&self.channel.to_le_bytes());
        b[8..12].copy_from_slice(&self.seq.to_le_bytes());
        b[12..20].copy_from_slice(&self.position_mm.to_le_bytes());
        b
    }
    pub fn decode(buf: &[u8]) -> Result<Self, DatagramError> {
        header(buf, INPUT_MAGIC, Self::SIZE)?;
        Ok(Self {
            channel: u32_at(buf, 4),
            seq: u32_at(buf, 8),
            position_mm: f64_at(buf, 12)?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn golden_bytes() {
        // Written out by hand from the table above: a C peer must produce exactly these.
        let cmd = RigCommand {
            seq: 0x0102_0304,
            valve: -2.5,
        };
        assert_eq!(
            cmd.encode(),
            [
                b'B', b'D', b'F', b'C', 4, 3, 2, 1, 0, 0, 0, 0, 0, 0, 0x04, 0xc0
            ]
        );
        let st = RigState {
            seq: 7,
            cylinder_mm: 1.0,
            cab_accel_mm_s2: -0.5,
        };
        assert_eq!(
            st.encode(),
            [
                b'B', b'D', b'F', b'R', 7, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0xf0, 0x3f, 0, 0, 0, 0, 0, 0,
                0xe0, 0xbf
            ]
        );
        let inp = InputDatagram {
            channel: 2,
            seq: 9,
            position_mm: 2.0,
        };
        assert_eq!(
            inp.encode(),
            [
                b'B', b'D', b'F', b'I', 2, 0, 0, 0, 9, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x40
            ]
        );
    }

    #[test]
    fn round_trip_and_rejections() {
        let st = RigState {
            seq: 1,
            cylinder_mm: 12.5,
            cab_accel_mm_s2: 300.0,
        };
        assert_eq!(RigState::decode(&st.encode()), Ok(st));
        let inp = InputDatagram {
            channel: 3,
            seq: 4,
            position_mm: -7.25,
        };
        assert_eq!(InputDatagram::decode(&inp.encode()), Ok(inp));
        let cmd = RigCommand { seq: 5, valve: 9.5 };
        assert_eq!(RigCommand::decode(&cmd.encode()), Ok(cmd));
        assert_eq!(
            RigState::decode(&[0; 3]),
            Err(DatagramError::Size { got: 3, want: 24 })
        );
        assert!(matches!(
            RigState::decode(&cmd.encode()),
            Err(DatagramError::Size { .. })
        ));
        let mut bad = st.encode();
        bad[0] = b'X';
        assert!(matches!(
            RigState::decode(&bad),
            Err(DatagramError::Magic(_))
        ));
        let nan = InputDatagram {
            channel: 1,
            seq: 1,
            position_mm: f64::NAN,
        }
        .encode();
        assert_eq!(InputDatagram::decode(&nan), Err(DatagramError::NonFinite));
    }
}
