//! A test client for `bdft-controller serve`: spawns the real process and talks the real
//! protocol over a real socket, as the server will.

use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use bdft_protocol::PROTOCOL_VERSION;
use bdft_protocol::controller_to_server::{
    ControllerToServer, LiveSample, RecordChunk, TrialResult,
};
use bdft_protocol::framing::BlockingFramed;
use bdft_protocol::link_auth::{Bytes32, KEY_ENV, LinkKey, LinkRole};
use bdft_protocol::server_to_controller::{ServerToController, StartTrial};
use bdft_protocol::trial::{FaultKind, Outcome};

use crate::binary;

/// A running product process, killed when dropped.
#[derive(Debug)]
pub struct Proc {
    pub child: Child,
    /// The link key handed to the process (`BDFT_CONTROLLER_KEY`): a controller proves it
    /// and demands it of every client.
    pub key: LinkKey,
    /// Addresses the process printed ("listening on …", "input udp on …").
    pub addr: SocketAddr,
    pub input_udp: Option<SocketAddr>,
    /// What the process printed before its address line.
    pub banner: Vec<String>,
}

impl Proc {
    /// Starts `binary` with `args` and waits for the line announcing its address
    /// (`prefix ADDR` on stdout).
    pub fn spawn(bin: &str, args: &[&str], prefix: &str) -> Self {
        Self::try_spawn(bin, args, prefix, Stdio::inherit()).unwrap_or_else(|e| panic!("{e}"))
    }

    /// [`Proc::spawn`] with the process's standard error going to `stderr`; an error when
    /// it exits before announcing its address (e.g. its port is taken).
    pub fn try_spawn(
        bin: &str,
        args: &[&str],
        prefix: &str,
        stderr: Stdio,
    ) -> Result<Self, String> {
        Self::try_spawn_in(None, bin, args, prefix, stderr)
    }

    /// [`Proc::try_spawn`] in the working directory `dir` (the test's own when none): how
    /// relative paths in `args` are tried.
    pub fn try_spawn_in(
        dir: Option<&std::path::Path>,
        bin: &str,
        args: &[&str],
        prefix: &str,
        stderr: Stdio,
    ) -> Result<Self, String> {
        let key = LinkKey::generate().expect("random key");
        let mut command = Command::new(binary(bin));
        if let Some(dir) = dir {
            command.current_dir(dir);
        }
        let child = command
            .args(args)
            .env(KEY_ENV, key.to_hex())
            .env(
                "RUST_LOG",
                std::env::var("RUST_LOG").unwrap_or_else(|_| "warn".into()),
            )
            .stdout(Stdio::piped())
            .stderr(stderr)
            .spawn()
            .map_err(|e| format!("spawn {bin}: {e}"))?;
        // Owned by a Proc from here on, so a failed start still kills the process.
        let mut proc = Self {
            child,
            key,
            addr: SocketAddr::from(([0, 0, 0, 0], 0)),
            input_udp: None,
            banner: Vec::new(),
        };
        let mut lines = BufReader::new(proc.child.stdout.take().expect("stdout")).lines();
        loop {
            let Some(Ok(line)) = lines.next() else {
                return Err(format!(
                    "{bin} {} exited before announcing its address; it printed {:?}",
                    args.join(" "),
                    proc.banner
                ));
            };
            if let Some(a) = line.strip_prefix("input udp on ") {
                proc.input_udp = Some(a.parse().expect("address"));
            }
            if let Some(a) = line.strip_prefix(prefix) {
                proc.addr = a.trim().parse().expect("address");
                // Keep draining stdout so the process never blocks on a full pipe.
                std::thread::spawn(move || for _ in lines {});
                return Ok(proc);
            }
            proc.banner.push(line);
        }
    }

    pub fn controller(extra: &[&str]) -> Self {
        let mut args = vec!["serve", "--listen", "127.0.0.1:0"];
        args.extend_from_slice(extra);
        Self::spawn("bdft-controller", &args, "listening on ")
    }

    pub fn rig_sim() -> Self {
        Self::spawn(
            "bdft-controller",
            &["rig-sim", "--listen", "127.0.0.1:0"],
            "rig-sim listening on ",
        )
    }

    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill();
    }
}

/// `frames` copies of one operator-input frame for `trial_id`, back to back: what a flood
/// writes to a control connection in one go.
pub fn input_flood_batch(trial_id: u64, frames: usize) -> Vec<u8> {
    let frame = bdft_protocol::framing::encode(&ServerToController::OperatorInput {
        trial_id,
        seq: 1,
        position_mm: 3.0,
    })
    .expect("an input frame");
    frame.repeat(frames)
}

/// How long a test waits for any one message before failing (generous for debug builds on
/// a loaded 2-core machine; a healthy exchange takes milliseconds).
pub const PATIENCE: Duration = Duration::from_secs(60);

/// The server end of a controller link, framed by the protocol's one codec.
#[derive(Debug)]
pub struct Link {
    framed: BlockingFramed<TcpStream, ControllerToServer, ServerToController>,
}

impl Link {
    /// Connects, authenticates and, as the server does when it holds no latch, clears the
    /// E-stop the controller starts with; returns the link and the controller's `HelloAck`.
    pub fn connect(ctl: &Proc) -> (Self, ControllerToServer) {
        let (mut link, ack) = Self::hello(ctl);
        link.send(&ServerToController::ResetEStop {});
        // The reset is answered by a status; wait for it so the stream starts clean.
        loop {
            if let ControllerToServer::Status(s) = link.recv() {
                assert!(!s.estop_latched, "the reset cleared the latch");
                break;
            }
        }
        (link, ack)
    }

    /// Connects and authenticates the control connection only (the controller's E-stop
    /// stays as it is); the answer is the `HelloAck` or why not.
    pub fn hello(ctl: &Proc) -> (Self, ControllerToServer) {
        Self::hello_as(ctl.addr, &ctl.key, LinkRole::Control)
    }

    /// Connects and proves `key` for `role`, as the server does. The answer is returned
    /// unchecked; a `HelloAck`'s proof is checked against `key`.
    pub fn hello_as(addr: SocketAddr, key: &LinkKey, role: LinkRole) -> (Self, ControllerToServer) {
        let mut link = Self::raw(addr);
        let challenge = link.challenge();
        let nonce = Bytes32::random().expect("random nonce");
        link.send(&ServerToController::Hello {
            protocol_version: PROTOCOL_VERSION,
            client: "bdft-tests".into(),
            role,
            nonce,
            proof: key.server_proof(role, &challenge, &nonce),
        });
        let ack = link.recv();
        if let ControllerToServer::HelloAck { proof, .. } = &ack {
            assert!(
                key.verify_controller(role, &challenge, &nonce, proof),
                "the controller proves the key"
            );
        }
        (link, ack)
    }

    /// Connects without authenticating (the controller's challenge is waiting to be read).
    pub fn raw(addr: SocketAddr) -> Self {
        let stream = TcpStream::connect(addr).expect("connect to the controller");
        stream.set_read_timeout(Some(PATIENCE)).unwrap();
        stream.set_nodelay(true).unwrap();
        Self {
            framed: BlockingFramed::new(stream),
        }
    }

    /// Another handle on the connection's socket (to write raw bytes from another thread).
    pub fn stream_clone(&self) -> TcpStream {
        self.framed.get_ref().try_clone().expect("clone the socket")
    }

    /// Reads the controller's challenge, the first frame on every connection.
    pub fn challenge(&mut self) -> Bytes32 {
        match self.recv() {
            ControllerToServer::Challenge { nonce, .. } => nonce,
            other => panic!("expected the challenge, got {other:?}"),
        }
    }

    pub fn send(&mut self, msg: &ServerToController) {
        self.framed.send(msg).expect("send");
    }

    /// Raw bytes on the stream (hand-made frames, JSON that is no message).
    pub fn send_bytes(&mut self, bytes: &[u8]) {
        self.framed.get_mut().write_all(bytes).expect("send");
    }

    /// A JSON text as one frame, whatever it says.
    pub fn send_json(&mut self, text: &str) {
        let mut frame = (text.len() as u32).to_be_bytes().to_vec();
        frame.extend_from_slice(text.as_bytes());
        self.send_bytes(&frame);
    }

    /// Next message other than a heartbeat; panics on timeout or a closed link.
    pub fn recv(&mut self) -> ControllerToServer {
        self.try_recv().expect("the controller closed the link")
    }

    /// `None` if the controller closed the link (or broke it); panics on a timeout or on a
    /// message this protocol does not know.
    pub fn try_recv(&mut self) -> Option<ControllerToServer> {
        loop {
            let msg = match self.framed.recv() {
                Ok(Some(msg)) => msg.expect("a valid message"),
                Ok(None) => return None,
                Err(bdft_protocol::framing::FrameError::Io(e))
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    panic!("no message from the controller within {PATIENCE:?}")
                }
                Err(_) => return None,
            };
            if !matches!(msg, ControllerToServer::Heartbeat { .. }) {
                return Some(msg);
            }
        }
    }

    /// Starts a trial and reads until the controller confirms it.
    pub fn start_and_wait(&mut self, st: StartTrial) {
        let id = st.trial_id;
        self.send(&ServerToController::StartTrial(Box::new(st)));
        loop {
            if let ControllerToServer::TrialStarted { trial_id, .. } = self.recv()
                && trial_id == id
            {
                return;
            }
        }
    }

    /// Lockstep: runs `ticks` ticks, collecting what arrives until `Stepped`.
    pub fn step(&mut self, ticks: u32, into: &mut TrialLog) {
        self.send(&ServerToController::Step { ticks });
        loop {
            match self.recv() {
                ControllerToServer::Stepped { .. } => return,
                other => into.add(other),
            }
        }
    }

    /// Receives until the result of `trial_id` arrives, sending heartbeats meanwhile.
    pub fn until_result(&mut self, trial_id: u64, into: &mut TrialLog) -> TrialResult {
        let start = Instant::now();
        loop {
            assert!(start.elapsed() < PATIENCE, "no result for trial {trial_id}");
            self.send(&ServerToController::Heartbeat { seq: 0 });
            let msg = self.recv();
            if let ControllerToServer::TrialResult(r) = &msg
                && r.trial_id == trial_id
            {
                return (**r).clone();
            }
            into.add(msg);
        }
    }
}

/// Everything received about trials, by kind.
#[derive(Debug, Default)]
pub struct TrialLog {
    pub started: Vec<u64>,
    pub live: Vec<LiveSample>,
    pub chunks: Vec<RecordChunk>,
    pub results: Vec<TrialResult>,
    pub faults: Vec<ControllerToServer>,
    pub rejected: Vec<String>,
    pub other: Vec<ControllerToServer>,
}

impl TrialLog {
    pub fn add(&mut self, msg: ControllerToServer) {
        match msg {
            ControllerToServer::TrialStarted { trial_id, .. } => self.started.push(trial_id),
            ControllerToServer::Live(s) => self.live.push(s),
            ControllerToServer::RecordChunk(c) => self.chunks.push(c),
            ControllerToServer::TrialResult(r) => self.results.push(*r),
            ControllerToServer::Rejected { reason, .. } => self.rejected.push(reason),
            f @ ControllerToServer::Fault { .. } => self.faults.push(f),
            other => self.other.push(other),
        }
    }

    /// Asserts that `trial_id` has ended on a fault of kind `kind`; its result.
    pub fn assert_faulted(&self, trial_id: u64, kind: FaultKind) -> &TrialResult {
        let r = self
            .results
            .iter()
            .find(|r| r.trial_id == trial_id)
            .unwrap_or_else(|| panic!("trial {trial_id} has not ended"));
        assert!(
            matches!(r.outcome, Outcome::Faulted { fault, .. } if fault == kind),
            "trial {trial_id}: {:?}",
            r.outcome
        );
        r
    }

    /// The full record of a trial, channel by channel, checking the chunks are in order
    /// and contiguous.
    pub fn record(&self, trial_id: u64) -> Vec<Vec<f32>> {
        let mut channels: Vec<Vec<f32>> = Vec::new();
        let mut next_tick = 0;
        for (i, c) in self
            .chunks
            .iter()
            .filter(|c| c.trial_id == trial_id)
            .enumerate()
        {
            assert_eq!(c.index as usize, i, "chunks in order");
            assert_eq!(c.start_tick, next_tick, "chunks contiguous");
            if channels.is_empty() {
                channels = vec![Vec::new(); c.channels.len()];
            }
            for (all, part) in channels.iter_mut().zip(&c.channels) {
                all.extend_from_slice(part);
            }
            next_tick += c.channels[0].len() as u64;
        }
        channels
    }
}
