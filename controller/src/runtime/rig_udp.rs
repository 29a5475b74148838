//! The real-rig backend over UDP (controller side, used inside the tick) and `rig-sim`, which
//! plays the rig side with the validated model so the UDP path is tested end to end.
//!
//! Datagram layouts: `bdft_protocol::rig`. The controller sends one command per tick — zero
//! when no trial drives the rig — so the rig always knows the controller is alive.

use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use bdft_protocol::rig::{RigCommand, RigState};

use crate::model::{Measurement, Plant, saturate};
use crate::params::PlantParams;

/// Controller side: a non-blocking socket connected to the rig. Sending and draining
/// received datagrams are syscalls that never wait.
#[derive(Debug)]
pub struct UdpRig {
    socket: UdpSocket,
    latest: Measurement,
    last_rx_tick: Option<u64>,
    timeout_ticks: u64,
    v_max: f64,
    seq: u32,
    pub rejected: u64,
}

impl UdpRig {
    pub fn connect(rig: SocketAddr, timeout_ticks: u64, v_max: f64) -> std::io::Result<Self> {
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
            seq: 0,
            rejected: 0,
        })
    }

    /// Takes every datagram that has arrived; the newest valid one is the measurement.
    #[inline]
    pub fn poll(&mut self, tick: u64) {
        let mut buf = [0u8; 64];
        loop {
            match self.socket.recv(&mut buf) {
                Ok(n) => match RigState::decode(&buf[..n]) {
                    Ok(s) => {
                        self.latest = Measurement {
                            y: s.cylinder_mm,
                            cab_accel: s.cab_accel_mm_s2,
                        };
                        self.last_rx_tick = Some(tick);
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
