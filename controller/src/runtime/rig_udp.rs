//! The real-rig backend over UDP (controller side, used inside the tick) and `rig-sim`, which
//! plays the rig side with the validated model so the UDP path is tested end to end.
//!
//! Datagram layouts: `bdft_protocol::rig`. The controller sends one command per tick — zero
//! when no trial drives the rig — so the rig always knows the controller is alive.

use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use bdft_protocol::rig::{DatagramError, RigCommand, RigState};

use crate::model::{Measurement, Plant, saturate};
use crate::params::PlantParams;

/// Largest cab acceleration a reading may show (mm/s²): 5 g. The bench PID's limit cycle
/// peaks near 2.5 g; beyond 5 g the sensor or the datagram is wrong.
pub const MAX_PLAUSIBLE_ACCEL_MM_S2: f64 = 50_000.0;
/// A reply must echo one of this many most recent commands.
const ECHO_WINDOW: u32 = 1000;

/// What was wrong with an implausible reading (kept without allocating, in the tick).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Implausible {
    NotFinite,
    /// Cylinder position (mm) beyond the stroke.
    Cylinder(f64),
    /// Cab acceleration (mm/s²) beyond `MAX_PLAUSIBLE_ACCEL_MM_S2`.
    Acceleration(f64),
    /// The sequence number echoed, not one of the recent commands.
    Echo(u32),
}

impl std::fmt::Display for Implausible {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::NotFinite => write!(f, "a reading that is not a finite number"),
            Self::Cylinder(y) => write!(f, "cylinder at {y:.1} mm, beyond the stroke"),
            Self::Acceleration(a) => write!(
                f,
                "cab acceleration {a:.0} mm/s², beyond the plausible {MAX_PLAUSIBLE_ACCEL_MM_S2:.0}"
            ),
            Self::Echo(s) => write!(f, "a reply to command {s}, which was never sent"),
        }
    }
}

/// Controller side: a non-blocking socket connected to the rig. Sending and draining
/// received datagrams are syscalls that never wait.
#[derive(Debug)]
pub struct UdpRig {
    socket: UdpSocket,
    latest: Measurement,
    last_rx_tick: Option<u64>,
    timeout_ticks: u64,
    v_max: f64,
    /// Largest |cylinder position| a reading may show (mm): the stroke and a margin.
    max_cylinder_mm: f64,
    seq: u32,
    pub rejected: u64,
    /// An implausible reading since the loop last looked (`take_implausible`).
    implausible: Option<Implausible>,
}

impl UdpRig {
    pub fn connect(
        rig: SocketAddr,
        timeout_ticks: u64,
        v_max: f64,
        stroke_mm: f64,
    ) -> std::io::Result<Self> {
        let local: SocketAddr = if rig.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" }
            .parse()
            .expect("literal");
        let socket = UdpSocket::bind(local)?;
        socket.connect(rig)?;
        socket.set_nonblocking(true)?;
        Ok(Self {
            socket,
            latest: Measurement::default(),
            last_rx_tick: None,
            timeout_ticks,
            v_max,
            max_cylinder_mm: 1.1 * stroke_mm,
            seq: 0,
            rejected: 0,
            implausible: None,
        })
    }

    /// Checks a reading; an implausible one never becomes the measurement.
    fn check(&self, s: &RigState) -> Result<(), Implausible> {
        if !s.cylinder_mm.is_finite() || !s.cab_accel_mm_s2.is_finite() {
            return Err(Implausible::NotFinite);
        }
        if s.cylinder_mm.abs() > self.max_cylinder_mm {
            return Err(Implausible::Cylinder(s.cylinder_mm));
        }
        if s.cab_accel_mm_s2.abs() > MAX_PLAUSIBLE_ACCEL_MM_S2 {
            return Err(Implausible::Acceleration(s.cab_accel_mm_s2));
        }
        // The echo is of a command sent, at most ECHO_WINDOW commands ago.
        if self.seq.wrapping_sub(s.seq) >= ECHO_WINDOW {
            return Err(Implausible::Echo(s.seq));
        }
        Ok(())
    }

    /// The implausible reading seen since the last call, if any.
    #[inline]
    pub fn take_implausible(&mut self) -> Option<Implausible> {
        self.implausible.take()
    }

    /// Takes every datagram that has arrived; the newest valid one is the measurement.
    #[inline]
    pub fn poll(&mut self, tick: u64) {
        let mut buf = [0u8; 64];
        loop {
            match self.socket.recv(&mut buf) {
                Ok(n) => match RigState::decode(&buf[..n]) {
                    Ok(s) => match self.check(&s) {
                        Ok(()) => {
                            self.latest = Measurement {
                                y: s.cylinder_mm,
                                cab_accel: s.cab_accel_mm_s2,
                            };
                            self.last_rx_tick = Some(tick);
                        }
                        Err(why) => {
                            self.rejected += 1;
                            self.implausible = Some(why);
                        }
                    },
                    // A rig datagram whose readings are not numbers is a reading that
                    // cannot be true, not just noise on the wire.
                    Err(DatagramError::NonFinite) => {
                        self.rejected += 1;
                        self.implausible = Some(Implausible::NotFinite);
                    }
                    Err(_) => self.rejected += 1,
                },
                // WouldBlock: drained. ConnectionRefused: the rig is not up (ICMP); the
                // timeout will tell.
                Err(e) if e.kind() == ErrorKind::WouldBlock => return,
                Err(_) => return,
            }
        }
    }

    pub fn measurement(&self) -> Measurement {
        self.latest
    }

    /// True if nothing has come from the rig for longer than the timeout, counting from
    /// `since` at the earliest (a trial's first tick).
    #[inline]
    pub fn timed_out(&self, now: u64, since: u64) -> bool {
        let last = self.last_rx_tick.map_or(since, |t| t.max(since));
        now.saturating_sub(last) > self.timeout_ticks
    }

    #[inline]
    pub fn send(&mut self, valve: f64) {
        self.seq = self.seq.wrapping_add(1);
        let d = RigCommand {
            seq: self.seq,
            valve: saturate(valve, self.v_max),
        }
        .encode();
        // A full socket buffer drops this command; the next tick sends a fresh one.
        let _ = self.socket.send(&d);
    }
}

/// `bdft-controller rig-sim`: answers each command datagram by stepping the model one
/// sample with that valve command and replying with the sensors. Between trials (no command
/// for `idle_reset`) the rig returns to rest, like a machine set back to its start pose.
pub fn run_rig_sim(
    listen: SocketAddr,
    plant: PlantParams,
    dt: f64,
    seed: u64,
    idle_reset: Duration,
    mut ready: impl FnMut(SocketAddr),
) -> std::io::Result<()> {
    let socket = UdpSocket::bind(listen)?;
    ready(socket.local_addr()?);
    let fresh =
        || Plant::new(plant, dt, seed).map_err(|e| std::io::Error::new(ErrorKind::InvalidInput, e));
    let mut model = fresh()?;
    let mut last = Instant::now();
    let mut buf = [0u8; 64];
    let mut rejected = 0u64;
    loop {
        let (n, from) = socket.recv_from(&mut buf)?;
        let Ok(cmd) = RigCommand::decode(&buf[..n]) else {
            rejected += 1;
            if rejected.is_power_of_two() {
                tracing::warn!(rejected, "rig-sim: malformed command datagrams");
            }
            continue;
        };
        if last.elapsed() > idle_reset {
            model = fresh()?;
        }
        last = Instant::now();
        model.step(cmd.valve);
        let m = model.measure();
        let reply = RigState {
            seq: cmd.seq,
            cylinder_mm: m.y,
            cab_accel_mm_s2: m.cab_accel,
        };
        socket.send_to(&reply.encode(), from)?;
    }
}
