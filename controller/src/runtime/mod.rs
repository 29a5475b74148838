//! The real-time controller process (`bdft-controller serve`, `rig-sim`, `bench-rt`).
//!
//! Two sides: the loop thread ([`rt_loop`]) ticks every running trial at 1 kHz against
//! absolute deadlines; the I/O side ([`link`]) speaks the protocol with the server, builds
//! trials ([`setup`]) and sends their records. They share only lock-free queues, atomics and
//! the latest-value input cells ([`handoff`]).
//!
//! Files: `rt_loop`: the loop thread (absolute deadlines via `clock_nanosleep`, overruns counted
//! and skipped, lockstep mode), commands in and events out through `rtrb` SPSC queues; `slot`: a
//! trial as the loop holds it (built and allocated on the I/O side by `setup`, moved in and out by
//! pointer, record prefaulted); `handoff`: seqlock latest-value operator input; `histogram`:
//! allocation-free log-linear timing histograms; `rig_udp`: the UDP rig backend and `rig-sim`;
//! `os`: SCHED_FIFO, mlockall, affinity, the monotonic clock (the libc calls: `unsafe` allowed
//! here); `local`: a trial run to its end in the calling thread, without the clock (pilots, the
//! planner, the bench). The tokio side: `handshake` (pending-connection caps, the
//! challenge–response, the small pre-authentication frame limit), `link/` (the I/O side, its
//! imports running down to `link::state`, what its tasks share: `connection.rs` — accepting, the
//! one control connection's reader and writer —, `requests.rs` — validation of what the server
//! sends and the rules a trial must pass to start —, `pump.rs` — the event pump: live samples,
//! record chunks, results —, `heartbeat.rs` — heartbeats and the link watchdog —, `input_port.rs` —
//! the UDP input of a haptic host, pinned sender, increasing sequence), `estop_path` (the E-stop's
//! own connection: sets the loop's E-stop flag on arrival and confirms).
//!
//! *Invariants:* nothing a peer sends is read beyond the hello until its proof checks out. The loop
//! thread never allocates, locks, blocks or logs after start-up
//! (`rt_loop::tests::the_loop_tick_never_allocates`); it never frees a trial either — finished
//! slots go back to the I/O side.

pub mod estop_path;
pub mod handoff;
pub mod handshake;
pub mod histogram;
pub mod link;
pub mod local;
pub mod os;
pub mod rig_udp;
pub mod rt_loop;
pub mod setup;
pub mod slot;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;
use bdft_protocol::controller_to_server::RealtimeStatus;
use bdft_protocol::link_auth::{KEY_ENV, LinkKey};
use bdft_protocol::params::{CompensatorKind, PlantParams, Seat};
use bdft_protocol::server_to_controller::StartTrial;
use bdft_protocol::trial::{InputSource, TargetSpec, TimingSummary};
use serde::Serialize;

use crate::compensator::study_spec;
use crate::lsl::publisher::Publisher;
use crate::lsl::streams::{Scope, StreamTags};
use crate::lsl::tap;
use crate::operator::OperatorParams;
use crate::signals::{StepParams, StepTarget};
use rt_loop::{Command, Event, LoopConfig};

#[derive(Debug, Clone)]
pub struct ServeConfig {
    pub listen: SocketAddr,
    /// A real rig's address (UDP); `None` simulates the rig.
    pub rig: Option<SocketAddr>,
    pub rig_timeout: Duration,
    pub input_udp: Option<SocketAddr>,
    pub lockstep: bool,
    pub link_timeout: Duration,
    pub max_trials: usize,
    pub priority: i32,
    pub cpu: Option<usize>,
    pub dt: f64,
    /// Stop when standard input reaches end of file.
    pub exit_with_stdin: bool,
    /// The link key every server connection must prove.
    pub key: LinkKey,
    /// Publish the stations' signal streams over LSL, discoverable within this scope.
    pub lsl: Option<Scope>,
}

fn loop_config(
    dt: f64,
    lockstep: bool,
    max_trials: usize,
    priority: i32,
    cpu: Option<usize>,
) -> LoopConfig {
    LoopConfig {
        period_ns: (dt * 1e9).round() as u64,
        lockstep,
        max_trials,
        priority,
        cpu,
        rig: None,
        lsl: None,
    }
}

/// The command-line options of `serve`, shared by `bdft-controller serve` and the controller
/// the experiment server starts.
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// TCP address the server connects to (any address, so the controller can run on a
    /// dedicated real-time PC).
    #[arg(long, env = "BDFT_CONTROLLER_LISTEN", default_value = "127.0.0.1:7070")]
    pub listen: SocketAddr,
    /// Rig: sim (the validated model, one per trial) or udp (a real rig at --rig-addr).
    #[arg(long, default_value = "sim", value_parser = ["sim", "udp"])]
    pub rig: String,
    /// The real rig's UDP address (with --rig udp).
    #[arg(long, required_if_eq("rig", "udp"))]
    pub rig_addr: Option<SocketAddr>,
    /// A rig silent for this long faults the trial (ms).
    #[arg(long, default_value_t = 50, value_parser = clap::value_parser!(u64).range(2..=10_000))]
    pub rig_timeout_ms: u64,
    /// UDP port for a haptic-device host sending operator input (off by default).
    #[arg(long)]
    pub input_udp: Option<SocketAddr>,
    /// Run ticks only when the client asks (`step` messages): deterministic tests.
    #[arg(long)]
    pub lockstep: bool,
    /// Silence from the server for this long counts as a lost link (ms).
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u64).range(50..=600_000))]
    pub link_timeout_ms: u64,
    /// Most trials run at once (one per station).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub max_trials: u64,
    /// SCHED_FIFO priority asked for the loop thread.
    #[arg(long, default_value_t = 80, value_parser = clap::value_parser!(i32).range(1..=99))]
    pub priority: i32,
    /// CPU to pin the loop thread to [default: the last CPU when there are several].
    #[arg(long)]
    pub cpu: Option<usize>,
    /// Shut down when standard input closes (a supervising process that dies takes
    /// its controller with it).
    #[arg(long)]
    pub exit_with_stdin: bool,
    /// File with the link key a server must prove before anything it sends is read (64 hex
    /// digits, readable only by its owner; make one with `bdft-controller keygen FILE` and
    /// give the server the same file). Without it the key comes from BDFT_CONTROLLER_KEY,
    /// as the experiment server hands it to the controller it starts.
    #[arg(long, env = "BDFT_CONTROLLER_KEY_FILE")]
    pub key_file: Option<PathBuf>,
    /// Publish each station's 1 kHz signals as a Lab Streaming Layer stream (off by
    /// default: without it no LSL socket is opened).
    #[arg(long)]
    pub lsl: bool,
    /// How far LSL discovery answers: machine (this host only), link or site.
    #[arg(long, value_enum, default_value_t = Scope::Machine, requires = "lsl")]
    pub lsl_scope: Scope,
}

impl ServeArgs {
    /// The configuration, with the link key read; fails when there is no key (a controller
    /// anyone could drive is never started).
    pub fn config(&self) -> anyhow::Result<ServeConfig> {
        let key = match (&self.key_file, std::env::var(KEY_ENV)) {
            (Some(path), _) => LinkKey::load(path)?,
            (None, Ok(hex)) => LinkKey::from_hex(&hex).context(KEY_ENV)?,
            (None, Err(_)) => anyhow::bail!(
                "no link key: pass --key-file FILE (make one with `bdft-controller keygen FILE`) or set {KEY_ENV}"
            ),
        };
        Ok(ServeConfig {
            listen: self.listen,
            rig: if self.rig == "udp" {
                self.rig_addr
            } else {
                None
            },
            rig_timeout: Duration::from_millis(self.rig_timeout_ms),
            input_udp: self.input_udp,
            lockstep: self.lockstep,
            link_timeout: Duration::from_millis(self.link_timeout_ms),
            max_trials: self.max_trials as usize,
            priority: self.priority,
            cpu: self.cpu.or_else(default_cpu),
            dt: bdft_protocol::params::LoopParams::default().dt,
            exit_with_stdin: self.exit_with_stdin,
            key,
            lsl: self.lsl.then_some(self.lsl_scope),
        })
    }
}

/// `serve` as a command: announces its addresses on stdout (tools that start it with port 0
/// read these lines), then runs until stopped.
pub fn serve_announcing(args: &ServeArgs) -> anyhow::Result<()> {
    use std::io::Write;
    serve(args.config()?, |addr, input| {
        // A supervisor that is already gone has closed the pipe: nobody reads the lines, and
        // the loop stops when its stdin closes (`exit_with_stdin`). Writing must not panic.
        let mut out = std::io::stdout().lock();
        let written = input
            .map_or(Ok(()), |input| writeln!(out, "input udp on {input}"))
            .and_then(|()| writeln!(out, "listening on {addr}"))
            .and_then(|()| out.flush());
        if let Err(e) = written {
            tracing::warn!(error = %e, "the addresses could not be announced on standard output");
        }
    })
}

/// The CPU the loop asks to be pinned to by default: the last one, if there are several.
pub fn default_cpu() -> Option<usize> {
    let n = os::cpu_count();
    (n > 1).then(|| n - 1)
}

/// Runs `serve` until SIGINT/SIGTERM; `ready` gets the bound TCP address and the input UDP
/// address, if any (port 0 allowed).
pub fn serve(
    cfg: ServeConfig,
    ready: impl FnOnce(SocketAddr, Option<SocketAddr>),
) -> anyhow::Result<()> {
    let mut lc = loop_config(cfg.dt, cfg.lockstep, cfg.max_trials, cfg.priority, cfg.cpu);
    if let Some(addr) = cfg.rig {
        let ticks = (cfg.rig_timeout.as_secs_f64() / cfg.dt).round() as u64;
        lc.rig = Some(
            rig_udp::UdpRig::connect(
                addr,
                ticks,
                PlantParams::default().v_max,
                PlantParams::default().stroke_mm,
            )
            .with_context(|| format!("opening the UDP link to the rig at {addr}"))?,
        );
    }
    let lsl = match cfg.lsl {
        Some(scope) => {
            let (tap, publisher) = lsl_publisher(scope)?;
            lc.lsl = Some(tap);
            tracing::info!(
                scope = scope.as_str(),
                "LSL: the stations' signal streams are published"
            );
            Some(std::sync::Arc::new(publisher))
        }
        None => None,
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the I/O runtime")?;
    let mut rt = rt_loop::spawn(lc);
    // Fail-safe: the process starts with the E-stop latched, and only a connected server
    // clears it (it re-sends its own latch to every new connection). A controller that
    // restarts after an E-stop never comes up ready to move the machine.
    rt.shared
        .estop
        .store(true, std::sync::atomic::Ordering::SeqCst);
    let _ = rt.send(rt_loop::Command::EStop);
    tracing::info!("starting with the E-stop latched: the server clears it when it connects");
    let link_cfg = link::LinkConfig {
        dt: cfg.dt,
        lockstep: cfg.lockstep,
        real_rig: cfg.rig.is_some(),
        max_trials: cfg.max_trials,
        link_timeout: cfg.link_timeout,
        input_udp: cfg.input_udp.is_some(),
        key: cfg.key.clone(),
        lsl,
    };
    runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind(cfg.listen)
            .await
            .with_context(|| format!("listening on {}", cfg.listen))?;
        let input = match cfg.input_udp {
            Some(a) => Some(
                tokio::net::UdpSocket::bind(a)
                    .await
                    .with_context(|| format!("binding the input port {a}"))?,
            ),
            None => None,
        };
        // Before the ready line: whoever reads it may signal at once.
        let signalled = shutdown_signal();
        ready(
            listener.local_addr()?,
            input.as_ref().map(|s| s.local_addr()).transpose()?,
        );
        let stdin_closed = async move {
            if cfg.exit_with_stdin {
                let mut sink = Vec::new();
                let _ =
                    tokio::io::AsyncReadExt::read_to_end(&mut tokio::io::stdin(), &mut sink).await;
                tracing::warn!("standard input closed: the supervising process is gone; stopping");
            } else {
                std::future::pending::<()>().await;
            }
        };
        let stop = async move {
            tokio::select! {
                _ = signalled => {}
                _ = stdin_closed => {}
            }
        };
        link::run(link_cfg, rt, listener, input, stop).await;
        anyhow::Ok(())
    })?;
    tracing::info!("controller stopped");
    Ok(())
}

/// The loop's end of the LSL hand-over and the publisher reading it, LSL configured for
/// `scope` first.
fn lsl_publisher(scope: Scope) -> anyhow::Result<(tap::SampleTap, Publisher)> {
    scope.configure();
    let (tap, reader) = tap::tap(tap::CAPACITY);
    let publisher = Publisher::start(reader).context("starting the LSL publisher")?;
    Ok((tap, publisher))
}

/// Resolves on SIGINT or SIGTERM. The handlers are installed by this call, not when the
/// future is first polled: a signal that comes between a process's ready line and its first
/// wait must still stop it cleanly, not by the default action, which skips the clean-up (a
/// server's heartbeat left to go silent, a restore refused meanwhile). Call it in a runtime,
/// before the ready line.
pub fn shutdown_signal() -> impl std::future::Future<Output = ()> + Send + 'static {
    use tokio::signal::unix::{SignalKind, signal};
    let int = signal(SignalKind::interrupt()).ok();
    let term = signal(SignalKind::terminate()).ok();
    async move {
        tokio::select! {
            _ = received(int) => {}
            _ = received(term) => {}
        }
    }
}

/// Waits for `signal`; forever when its handler could not be installed.
async fn received(signal: Option<tokio::signal::unix::Signal>) {
    match signal {
        Some(mut s) => {
            s.recv().await;
        }
        None => std::future::pending().await,
    }
}

/// What `bench-rt` prints.
#[derive(Debug, Serialize)]
pub struct BenchReport {
    pub trials: usize,
    pub duration_s: f64,
    /// With `--lsl`: rows the hand-over dropped (its publisher fell behind).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lsl_dropped: Option<u64>,
    #[serde(flatten)]
    pub timing: TimingSummary,
    pub realtime: RealtimeStatus,
}

/// Trial `i` of `bench-rt`: the five study compensators in turn with their designs for people
/// (`study_spec`: the bench PID limit-cycles on the machine, the interlock stops it within
/// 3 s, and the loop would be timed with fewer trials than asked), a synthetic operator,
/// station on, random steps; each trial its own seeds.
pub fn bench_trial(i: usize, duration_s: f64) -> anyhow::Result<StartTrial> {
    let plant = PlantParams::default();
    let kind = CompensatorKind::STUDY[i % CompensatorKind::STUDY.len()];
    let target = StepTarget::generate(&StepParams::default(), duration_s.max(4.0), i as u64)?;
    Ok(StartTrial {
        trial_id: i as u64 + 1,
        compensator: study_spec(kind, &plant),
        seat: Seat::On,
        k_bf: 0.6,
        target: TargetSpec::Steps {
            interval_s: target.interval_s,
            levels_mm: target.levels_mm,
        },
        duration_s,
        input: InputSource::Synthetic {
            operator: OperatorParams::default(),
            seed: i as u64,
        },
        plant,
        body: Default::default(),
        noise_seed: i as u64,
        live_rate_hz: 100.0,
        stale_input_ms: 100.0,
        max_cab_rms_mm_s2: bdft_protocol::server_to_controller::DEFAULT_MAX_CAB_RMS_MM_S2,
        exposure_allowance: None,
        cancellation: None,
        condition: Default::default(),
    })
}

/// Runs `trials` simulated trials (the five study compensators in turn, synthetic
/// operators, station on) in real time for `duration_s` and reports the loop's timing.
///
/// With `lsl`, every trial's signals also go through the LSL hand-over to one stream
/// ("bench", machine scope), as `serve --lsl` sends a station's: the loop's cost of it shows
/// in the timing.
pub fn bench_rt(
    duration_s: f64,
    trials: usize,
    cpu: Option<usize>,
    priority: i32,
    lsl: bool,
) -> anyhow::Result<BenchReport> {
    let dt = 1e-3;
    let mut lc = loop_config(dt, false, trials.max(1), priority, cpu);
    let publisher = if lsl {
        let (tap, publisher) = lsl_publisher(Scope::Machine)?;
        lc.lsl = Some(tap);
        publisher.station(StreamTags {
            station_id: 0,
            station: "bench".into(),
            study_id: 0,
            study: "bench-rt".into(),
            subject: "none".into(),
        })?;
        Some(publisher)
    } else {
        None
    };
    let mut rt = rt_loop::spawn(lc);
    for i in 0..trials {
        let st = bench_trial(i, duration_s)?;
        if let Some(p) = &publisher {
            p.route(st.trial_id, 0);
        }
        let built = setup::build_slot(&st, dt, false).map_err(anyhow::Error::msg)?;
        rt.send(Command::Start(built.slot))
            .map_err(|_| anyhow::anyhow!("command queue full"))?;
    }
    // Drain events as a server link would, until every trial has come back.
    let mut finished = 0;
    while finished < trials {
        while let Ok(ev) = rt.events.pop() {
            if let Event::Finished(_) = ev {
                finished += 1;
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let realtime = rt.shared.realtime.get().cloned().unwrap_or_default();
    let stats = rt.shutdown();
    Ok(BenchReport {
        trials,
        duration_s,
        lsl_dropped: publisher.map(|p| p.dropped()),
        timing: TimingSummary {
            ticks: stats.ticks,
            overruns: stats.overruns,
            wake_latency_us: stats.wake.percentiles_us(),
            compute_us: stats.compute.percentiles_us(),
        },
        realtime,
    })
}
