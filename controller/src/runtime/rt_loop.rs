//! The 1 kHz loop: one `std::thread` that wakes at absolute deadlines and ticks every
//! running trial. It talks to the rest of the process only through lock-free queues
//! (commands in, events out) and a few atomics; inside the tick nothing allocates, locks,
//! blocks or logs.

use std::sync::Arc;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::{JoinHandle, Thread};
use std::time::Duration;

use bdft_protocol::controller_to_server::{LiveSample, RealtimeStatus};
use bdft_protocol::trial::{FaultKind, TrialId};
use rtrb::{Consumer, Producer, RingBuffer};

use super::histogram::Histogram;
use super::os;
use super::rig_udp::UdpRig;
use super::slot::{EndReason, SlotLoop, SlotTick, TrialSlot};
use crate::lsl::tap::SampleTap;

/// State the loop publishes for the I/O side.
#[derive(Debug, Default)]
pub struct Shared {
    /// Ticks run so far (operator input is stamped with it on arrival).
    pub tick: AtomicU64,
    pub overruns: AtomicU64,
    /// E-stop requested or latched. Setting it stops every trial at the next tick even if
    /// the command queue is congested.
    pub estop: AtomicBool,
    pub rig_rejected: AtomicU64,
    pub realtime: OnceLock<RealtimeStatus>,
}

#[derive(Debug)]
pub enum Command {
    Start(Box<TrialSlot>),
    Abort(TrialId),
    EStop,
    ResetEStop,
    /// End every running trial with this fault (link lost, shutdown).
    StopAll(FaultKind),
    /// Lockstep: run this many more ticks.
    Step(u32),
    Shutdown,
}

#[derive(Debug)]
pub enum Event {
    Started {
        trial_id: TrialId,
        tick: u64,
    },
    Live(LiveSample),
    /// The trial ended; its slot (record, metrics, timing) comes back to be sent and freed.
    Finished(Box<TrialSlot>),
    Stepped {
        tick: u64,
    },
}

#[derive(Debug)]
pub struct LoopConfig {
    pub period_ns: u64,
    pub lockstep: bool,
    pub max_trials: usize,
    pub priority: i32,
    pub cpu: Option<usize>,
    pub rig: Option<UdpRig>,
    /// The hand-over of every tick's signals to the LSL publisher (`--lsl`).
    pub lsl: Option<SampleTap>,
}

/// Whole-run timing of the loop.
#[derive(Debug, Clone, Default)]
pub struct LoopStats {
    pub ticks: u64,
    pub overruns: u64,
    pub wake: Histogram,
    pub compute: Histogram,
}

/// The I/O side's handle on the loop.
#[derive(Debug)]
pub struct LoopHandle {
    commands: Producer<Command>,
    pub events: Consumer<Event>,
    pub shared: Arc<Shared>,
    thread: Thread,
    join: Option<JoinHandle<LoopStats>>,
}

impl LoopHandle {
    /// Queues a command (and wakes a lockstep loop); gives it back if the queue is full.
    pub fn send(&mut self, cmd: Command) -> Result<(), Command> {
        let r = self
            .commands
            .push(cmd)
            .map_err(|rtrb::PushError::Full(c)| c);
        self.thread.unpark();
        r
    }

    /// Stops the loop and returns its timing.
    pub fn shutdown(mut self) -> LoopStats {
        let _ = self.send(Command::Shutdown);
        self.join
            .take()
            .map(|j| j.join().unwrap_or_default())
            .unwrap_or_default()
    }
}

/// Room kept in the event queue for control events: live samples are dropped before it fills.
const EVENT_RESERVE: usize = 1024;

pub fn spawn(cfg: LoopConfig) -> LoopHandle {
    let (rt, commands, events, shared) = RtLoop::new(cfg);
    let join = std::thread::Builder::new()
        .name("bdft-rt".into())
        .spawn(move || rt.run())
        .expect("spawn the real-time thread");
    LoopHandle {
        commands,
        events,
        shared,
        thread: join.thread().clone(),
        join: Some(join),
    }
}

struct RtLoop {
    cfg: LoopConfig,
    slots: Vec<Option<Box<TrialSlot>>>,
    /// Finished slots waiting for room in the event queue (never dropped here: freeing
    /// memory is the I/O side's job).
    pending: Vec<Box<TrialSlot>>,
    commands: Consumer<Command>,
    events: Producer<Event>,
    shared: Arc<Shared>,
    tick: u64,
    overruns: u64,
    budget: u64,
    latched: bool,
    shutdown: bool,
    stats: LoopStats,
}

impl RtLoop {
    fn new(cfg: LoopConfig) -> (Self, Producer<Command>, Consumer<Event>, Arc<Shared>) {
        let (cmd_tx, cmd_rx) = RingBuffer::new(1024);
        let (mut ev_tx, mut ev_rx) = RingBuffer::new(1 << 16);
        // Touch every page of the event queue now, so that without locked memory the tick
        // does not take a page fault every ~57 events on fresh pages.
        while ev_tx.push(Event::Stepped { tick: 0 }).is_ok() {}
        while ev_rx.pop().is_ok() {}
        let shared = Arc::new(Shared::default());
        let rt = Self {
            slots: (0..cfg.max_trials).map(|_| None).collect(),
            pending: Vec::with_capacity(4 * cfg.max_trials + 16),
            commands: cmd_rx,
            events: ev_tx,
            shared: Arc::clone(&shared),
            tick: 0,
            overruns: 0,
            budget: 0,
            latched: false,
            shutdown: false,
            stats: LoopStats::default(),
            cfg,
        };
        (rt, cmd_tx, ev_rx, shared)
    }

    fn run(mut self) -> LoopStats {
        let status = if self.cfg.lockstep {
            tracing::info!("lockstep mode: the loop runs only the ticks the client asks for");
            RealtimeStatus::default()
        } else {
            let (status, refused) = os::make_realtime(self.cfg.priority, self.cfg.cpu);
            for r in &refused {
                tracing::warn!("real-time loop: {r}");
            }
            if refused.is_empty() {
                tracing::info!(
                    ?status,
                    "real-time loop: SCHED_FIFO, memory locked, CPU pinned"
                );
            }
            status
        };
        let _ = self.shared.realtime.set(status);
        let period = self.cfg.period_ns;
        let mut deadline = os::now_ns() + period;
        loop {
            let (wake, latency) = if self.cfg.lockstep {
                loop {
                    self.drain_commands();
                    if self.shutdown || self.budget > 0 {
                        break;
                    }
                    std::thread::park_timeout(Duration::from_millis(10));
                }
                (os::now_ns(), 0)
            } else {
                os::sleep_until(deadline);
                let wake = os::now_ns();
                self.drain_commands();
                (wake, wake.saturating_sub(deadline))
            };
            if self.shutdown {
                self.stop_all(EndReason::Faulted(FaultKind::Internal));
                self.flush_pending();
                return self.stats;
            }
            let end = self.one_tick(wake, latency);
            if self.cfg.lockstep {
                self.budget -= 1;
                if self.budget == 0 {
                    let _ = self.events.push(Event::Stepped { tick: self.tick });
                }
            } else {
                deadline += period;
                if end > deadline {
                    // Deadlines already missed are skipped, not caught up with a burst.
                    let missed = (end - deadline) / period + 1;
                    self.overruns += missed;
                    self.stats.overruns += missed;
                    deadline += missed * period;
                    self.shared.overruns.store(self.overruns, Ordering::Relaxed);
                }
            }
        }
    }

    /// Ticks every trial, records the timing, and hands back trials that ended. Returns
    /// the time the work finished.
    #[inline]
    fn one_tick(&mut self, wake: u64, latency: u64) -> u64 {
        self.tick_all(wake, latency);
        let end = os::now_ns();
        let compute = end.saturating_sub(wake);
        self.stats.ticks += 1;
        self.stats.wake.record(latency);
        self.stats.compute.record(compute);
        for slot in self.slots.iter_mut().flatten() {
            slot.wake.record(latency);
            slot.compute.record(compute);
            slot.overruns = self.overruns - slot.overruns_at_start;
        }
        // Trials that ended this tick leave only now, with this tick's timing counted.
        for i in 0..self.slots.len() {
            if self.slots[i].as_ref().is_some_and(|s| s.end.is_some()) {
                let slot = self.slots[i].take().expect("checked");
                self.finish(slot);
            }
        }
        end
    }

    fn drain_commands(&mut self) {
        while let Ok(cmd) = self.commands.pop() {
            match cmd {
                Command::Start(mut slot) => {
                    slot.overruns_at_start = self.overruns;
                    if self.latched {
                        slot.end(EndReason::Faulted(FaultKind::EStop));
                        self.finish(slot);
                    } else if let Some(i) = self.slots.iter().position(Option::is_none) {
                        let trial_id = slot.trial_id;
                        slot.live_phase = i as u64 % slot.live_every;
                        self.slots[i] = Some(slot);
                        let _ = self.events.push(Event::Started {
                            trial_id,
                            tick: self.tick,
                        });
                    } else {
                        slot.end(EndReason::Faulted(FaultKind::Internal));
                        self.finish(slot);
                    }
                }
                Command::Abort(id) => {
                    for i in 0..self.slots.len() {
                        if self.slots[i].as_ref().is_some_and(|s| s.trial_id == id) {
                            self.end_slot(i, EndReason::Aborted);
                        }
                    }
                }
                Command::EStop => {
                    self.shared.estop.store(true, Ordering::SeqCst);
                    self.latch_estop();
                }
                Command::ResetEStop => {
                    self.latched = false;
                    self.shared.estop.store(false, Ordering::SeqCst);
                }
                Command::StopAll(kind) => self.stop_all(EndReason::Faulted(kind)),
                Command::Step(n) => self.budget += u64::from(n),
                Command::Shutdown => self.shutdown = true,
            }
        }
    }

    fn latch_estop(&mut self) {
        if !self.latched {
            self.latched = true;
            self.stop_all(EndReason::Faulted(FaultKind::EStop));
        }
    }

    fn stop_all(&mut self, reason: EndReason) {
        for i in 0..self.slots.len() {
            self.end_slot(i, reason);
        }
    }

    fn end_slot(&mut self, i: usize, reason: EndReason) {
        if let Some(mut slot) = self.slots[i].take() {
            slot.end(reason);
            self.finish(slot);
        }
    }

    fn finish(&mut self, slot: Box<TrialSlot>) {
        self.flush_pending();
        if let Err(rtrb::PushError::Full(Event::Finished(slot))) =
            self.events.push(Event::Finished(slot))
        {
            if self.pending.len() < self.pending.capacity() {
                self.pending.push(slot);
            } else {
                // Cannot happen with a 65,536-event queue drained every millisecond; if it
                // did, losing the record beats blocking the loop.
                drop(slot);
            }
        }
    }

    fn flush_pending(&mut self) {
        while let Some(slot) = self.pending.pop() {
            if let Err(rtrb::PushError::Full(Event::Finished(slot))) =
                self.events.push(Event::Finished(slot))
            {
                self.pending.push(slot);
                return;
            }
        }
    }

    #[inline]
    fn tick_all(&mut self, wake_ns: u64, latency_ns: u64) {
        if self.shared.estop.load(Ordering::Relaxed) {
            self.latch_estop();
        }
        let now = self.tick;
        let mut implausible = None;
        if let Some(rig) = &mut self.cfg.rig {
            rig.poll(now);
            implausible = rig.take_implausible();
        }
        let latency_us = latency_ns as f32 / 1e3;
        let mut rig_command = 0.0;
        for i in 0..self.slots.len() {
            let Some(slot) = self.slots[i].as_mut() else {
                continue;
            };
            if let (SlotLoop::Rig(ext), Some(rig)) = (slot.runner.loop_mut(), self.cfg.rig.as_ref())
            {
                if let Some(why) = implausible {
                    slot.rig_fault = Some(why);
                    slot.end(EndReason::Faulted(FaultKind::RigImplausible));
                } else if rig.timed_out(now, slot.start_tick.unwrap_or(now)) {
                    slot.end(EndReason::Faulted(FaultKind::RigTimeout));
                } else {
                    ext.measurement = rig.measurement();
                }
            }
            if slot.end.is_none() {
                let rows = slot.record.len();
                let tick = slot.tick(now, wake_ns, latency_us);
                if let (Some(tap), Some(row)) = (&mut self.cfg.lsl, slot.record.get(rows)) {
                    tap.offer(slot.trial_id, wake_ns, row);
                }
                match tick {
                    SlotTick::Live(s) if self.events.slots() > EVENT_RESERVE => {
                        let _ = self.events.push(Event::Live(s));
                    }
                    _ => {}
                }
                if let SlotLoop::Rig(ext) = slot.runner.loop_mut() {
                    if slot.end.is_none() || slot.end == Some(EndReason::Complete) {
                        rig_command = ext.command;
                    }
                }
            }
        }
        if let Some(rig) = &mut self.cfg.rig {
            rig.send(if self.latched { 0.0 } else { rig_command });
            self.shared
                .rig_rejected
                .store(rig.rejected, Ordering::Relaxed);
        }
        self.tick += 1;
        self.shared.tick.store(self.tick, Ordering::Release);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::alloc_check::allocations_during;
    use crate::compensator::default_spec;
    use crate::runtime::handoff::InputSample;
    use crate::runtime::setup::build_slot;
    use bdft_protocol::params::{CompensatorKind, OperatorParams, PlantParams, Seat};
    use bdft_protocol::server_to_controller::StartTrial;
    use bdft_protocol::trial::{InputSource, TargetSpec};

    fn start(id: u64, kind: CompensatorKind, input: InputSource) -> StartTrial {
        let plant = PlantParams::default();
        StartTrial {
            trial_id: id,
            compensator: default_spec(kind, &plant),
            seat: Seat::On,
            k_bf: 0.6,
            target: TargetSpec::Steps {
                interval_s: 0.5,
                levels_mm: vec![10.0, -20.0, 5.0, 0.0],
            },
            duration_s: 1.5,
            input,
            plant,
            body: Default::default(),
            noise_seed: id,
            live_rate_hz: 100.0,
            stale_input_ms: 100.0,
            max_cab_rms_mm_s2: bdft_protocol::server_to_controller::DEFAULT_MAX_CAB_RMS_MM_S2,
            exposure_allowance: None,
            cancellation: None,
            condition: Default::default(),
        }
    }

    fn test_loop() -> (RtLoop, Producer<Command>, Consumer<Event>) {
        test_loop_with(None)
    }

    fn test_loop_with(lsl: Option<SampleTap>) -> (RtLoop, Producer<Command>, Consumer<Event>) {
        let cfg = LoopConfig {
            period_ns: 1_000_000,
            lockstep: true,
            max_trials: 8,
            priority: 1,
            cpu: None,
            rig: None,
            lsl,
        };
        let (rt, commands, events, _shared) = RtLoop::new(cfg);
        (rt, commands, events)
    }

    #[test]
    fn the_loop_tick_never_allocates() {
        // With the LSL hand-over, its ring small enough to fill: handing over and dropping
        // rows allocate nothing either.
        let (tap, reader) = crate::lsl::tap::tap(4096);
        let (mut rt, mut commands, mut events) = test_loop_with(Some(tap));
        let mut cells = Vec::new();
        for (i, kind) in CompensatorKind::ALL.into_iter().enumerate() {
            let input = if i % 2 == 0 {
                InputSource::Server
            } else {
                InputSource::Synthetic {
                    operator: OperatorParams::default(),
                    seed: i as u64,
                }
            };
            let built = build_slot(&start(i as u64, kind, input), 1e-3, false).unwrap();
            cells.extend(built.input);
            commands.push(Command::Start(built.slot)).unwrap();
        }
        commands.push(Command::Abort(4)).unwrap();
        let mut finished = 0;
        // Everything the loop does from installing trials to handing them back, with input
        // arriving every tick: no allocation.
        let n = allocations_during(|| {
            for k in 0..2000u64 {
                for cell in &cells {
                    cell.write(InputSample {
                        position_mm: 5.0,
                        seq: k,
                        arrival_tick: rt.tick,
                    });
                }
                rt.drain_commands();
                rt.one_tick(k * 1_000_000, 1_000);
            }
        });
        while let Ok(ev) = events.pop() {
            if let Event::Finished(slot) = ev {
                finished += 1;
                assert!(slot.end.is_some());
            }
        }
        assert_eq!(n, 0, "the loop allocated {n} times");
        assert!(reader.dropped() > 0, "the ring filled and dropped rows");
        assert_eq!(
            finished,
            CompensatorKind::ALL.len(),
            "every trial ended (one aborted, the others complete)"
        );
    }

    #[test]
    fn the_lsl_hand_over_carries_every_recorded_tick_of_a_trial() {
        let (tap, mut reader) = crate::lsl::tap::tap(crate::lsl::tap::CAPACITY);
        let (mut rt, mut commands, mut events) = test_loop_with(Some(tap));
        let st = start(
            3,
            CompensatorKind::Pid,
            InputSource::Synthetic {
                operator: OperatorParams::default(),
                seed: 3,
            },
        );
        let built = build_slot(&st, 1e-3, false).unwrap();
        commands.push(Command::Start(built.slot)).unwrap();
        for k in 0..2000u64 {
            rt.drain_commands();
            rt.one_tick(k * 1_000_000, 1_000);
        }
        let slot = std::iter::from_fn(|| events.pop().ok())
            .find_map(|e| match e {
                Event::Finished(slot) => Some(slot),
                _ => None,
            })
            .expect("the trial ended");
        let rows: Vec<_> = std::iter::from_fn(|| reader.ring.pop().ok()).collect();
        assert_eq!(rows.len(), slot.record.len(), "one row per recorded tick");
        assert_eq!(rows.len(), 1500);
        let columns = crate::lsl::streams::signal_columns();
        for (k, (row, recorded)) in rows.iter().zip(&slot.record).enumerate() {
            assert_eq!(row.trial_id, 3);
            assert_eq!(row.stamp_ns, k as u64 * 1_000_000, "stamped with its tick");
            assert_eq!(row.values, columns.map(|c| recorded[c]));
        }
        assert_eq!(reader.dropped(), 0);
    }

    #[test]
    fn new_input_is_echoed_by_a_live_sample_at_the_tick_that_uses_it() {
        let (mut rt, mut commands, mut events) = test_loop();
        let built = build_slot(
            &start(1, CompensatorKind::Pid, InputSource::Server),
            1e-3,
            false,
        )
        .unwrap();
        let cell = built.input.unwrap();
        commands.push(Command::Start(built.slot)).unwrap();
        rt.drain_commands();
        // Input at ~60 Hz (every 17 ticks): each one echoed on the tick it arrives.
        let mut live = Vec::new();
        for k in 0..1_000u64 {
            if k % 17 == 0 {
                cell.write(InputSample {
                    position_mm: 1.0,
                    seq: k / 17 + 1,
                    arrival_tick: rt.tick,
                });
            }
            rt.one_tick(k * 1_000_000, 1_000);
            while let Ok(ev) = events.pop() {
                if let Event::Live(s) = ev {
                    live.push((k, s.input_seq));
                }
            }
        }
        for k in (17..1_000u64).step_by(17) {
            assert!(
                live.contains(&(k, k / 17 + 1)),
                "input {} (tick {k}) not echoed at once: {live:?}",
                k / 17 + 1
            );
        }
        // Input every tick: the echoes are spaced, the live rate stays bounded.
        let before = live.len();
        for k in 1_000..1_400u64 {
            cell.write(InputSample {
                position_mm: 1.0,
                seq: k,
                arrival_tick: rt.tick,
            });
            rt.one_tick(k * 1_000_000, 1_000);
            while let Ok(ev) = events.pop() {
                if let Event::Live(s) = ev {
                    live.push((k, s.input_seq));
                }
            }
        }
        let n = live.len() - before;
        // 200 echoes (one per 2 ticks) and 40 regular samples, some on the same tick.
        assert!(
            (200..=240).contains(&n),
            "{n} live samples in 400 ticks of 1 kHz input"
        );
    }

    #[test]
    fn the_loop_tick_takes_no_page_fault_once_every_trial_has_run_a_second() {
        // Memory is not locked in a test, as in a controller without the privilege: a page
        // touched for the first time in the tick is a page fault there. The record and the
        // event queue grow through fresh memory all trial long; the rings of the interlock
        // and the operator are all touched within the first second. The LSL ring, emptied
        // as its publisher does, cycles through its pages: they were touched when it was made.
        let (tap, mut reader) = crate::lsl::tap::tap(crate::lsl::tap::CAPACITY);
        let (mut rt, mut commands, mut events) = test_loop_with(Some(tap));
        for i in 0..8 {
            let operator = InputSource::Synthetic {
                operator: OperatorParams::default(),
                seed: i,
            };
            let kind = CompensatorKind::STUDY[i as usize % CompensatorKind::STUDY.len()];
            let mut st = start(i, kind, operator);
            st.duration_s = 10.0;
            // Designs that do not trip the vibration interlock: every trial runs throughout.
            st.compensator = crate::compensator::study_spec(kind, &st.plant);
            let built = build_slot(&st, 1e-3, false).unwrap();
            commands.push(Command::Start(built.slot)).unwrap();
        }
        rt.drain_commands();
        let mut tick = |rt: &mut RtLoop, k: u64| {
            rt.one_tick(k * 1_000_000, 1_000);
            // The I/O side empties the queue, as the link does; the publisher the ring.
            while events.pop().is_ok() {}
            while reader.ring.pop().is_ok() {}
        };
        for k in 0..1_500 {
            tick(&mut rt, k);
        }
        let before = os::minor_faults();
        for k in 1_500..4_500 {
            tick(&mut rt, k);
        }
        // Without the prefaulting: a fault every ~110 record rows and every ~57 events, about
        // 220 in these 3 s of 8 trials.
        let faults = os::minor_faults() - before;
        assert!(faults < 20, "{faults} page faults in 3,000 ticks");
        assert!(rt.slots.iter().all(Option::is_some), "still running");
    }
}
