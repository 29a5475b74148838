//! Injecting each fault, journaling what was done and what is expected, and waiting for the
//! lab to recover from it. What a fault must not do to the tests it hit is judged at the end
//! against the exports (`verify`); what can only be seen while it happens is judged here.

use std::time::{Duration, Instant};

use serde_json::{Value, json};

use super::journal::wall_ms;
use super::plan::{Fault, FaultKind};
use super::station::Command;
use super::{RECOVERY, Running, Soak, TRIAL_S, host};
use crate::server::Stop;

/// How long a fault waits for a test to hit before it is injected anyway.
const WAIT_FOR_A_TEST: Duration = Duration::from_secs(20);

impl Soak {
    /// Injects `f` (step `n` of the plan) and waits for the lab to recover.
    pub(crate) fn inject(&mut self, f: Fault, n: usize) {
        match f.kind {
            FaultKind::ServerRestart => self.restart_server(f, n),
            FaultKind::DiskFull => self.fill_disk(f, n),
            FaultKind::StoreHeld => self.hold_store(f, n),
            FaultKind::ControllerKill | FaultKind::ControllerStop => self.break_controller(f, n),
            FaultKind::StationReload
            | FaultKind::StationOffline
            | FaultKind::StationHidden
            | FaultKind::StationFlood => self.break_station(f, n),
            FaultKind::SlowClients => self.slow_clients(f, n),
        }
    }

    fn fault(&self, f: Fault, n: usize, affected: &[Running], fields: Value, expected: &str) {
        let mut entry = json!({ "n": n, "kind": f.kind.name(), "expected": expected,
            "affected": affected.iter().map(|r| json!({ "trial": r.trial, "station": r.station,
                "started_at": r.started_at, "ends_at": r.ends_at })).collect::<Vec<_>>() });
        if let (Some(e), Value::Object(more)) = (entry.as_object_mut(), fields) {
            e.extend(more);
        }
        self.journal.log("fault", entry);
    }

    fn outcome(&self, f: Fault, n: usize, fields: Value) {
        let mut entry = json!({ "n": n, "kind": f.kind.name() });
        if let (Some(e), Value::Object(more)) = (entry.as_object_mut(), fields) {
            e.extend(more);
        }
        self.journal.log("fault.outcome", entry);
    }

    /// The controller as the dashboard sees it: (connected, pid).
    fn controller(&self) -> Option<(bool, Option<u32>)> {
        let (code, c) = self.api.try_call("GET", "/api/controller", None).ok()?;
        (code == 200).then(|| (c["connected"] == true, c["pid"].as_u64().map(|p| p as u32)))
    }

    fn restart_server(&mut self, f: Fault, n: usize) {
        let affected = self.running_with(WAIT_FOR_A_TEST, 1.0);
        let how = if f.choice.is_multiple_of(2) {
            Stop::Kill
        } else {
            Stop::Term
        };
        let old = self.server.proc.addr;
        self.fault(
            f,
            n,
            &affected,
            json!({ "signal": if how == Stop::Kill { "KILL" } else { "TERM" }, "pid": self.server.proc.child.id() }),
            "the tests running are filed incomplete (server restart); the server serves again on its port, the controller reconnects, every station page reconnects",
        );
        let began = Instant::now();
        self.server_expected = false;
        let restarted = self.server.restart(how, RECOVERY);
        self.server_expected = true;
        if let Err(e) = restarted {
            self.journal
                .violation(format!("restarting the server: {e}"));
            return;
        }
        self.server_started();
        let serving_ms = ms(began);
        let controller = self.wait_until(RECOVERY, |s| s.controller().is_some_and(|c| c.0));
        let controller_ms = ms(began);
        let stations = self.wait_until(RECOVERY, |s| s.stations.iter().all(|st| st.connected()));
        self.outcome(
            f,
            n,
            json!({ "serving_after_ms": serving_ms, "controller_after_ms": controller.then_some(controller_ms),
                "stations_after_ms": stations.then_some(ms(began)), "same_port": self.server.proc.addr == old }),
        );
        if !controller || !stations {
            self.journal.violation(format!(
                "after the server restart: {} within {RECOVERY:?}",
                if controller {
                    "not every station reconnected"
                } else {
                    "the controller did not reconnect"
                }
            ));
        }
    }

    fn break_controller(&mut self, f: Fault, n: usize) {
        let affected = self.running_with(WAIT_FOR_A_TEST, 0.5);
        let Some((true, Some(pid))) = self.controller() else {
            self.journal.violation(
                "the controller was not connected (or had no pid) when it was to be broken",
            );
            return;
        };
        let (signal, expected) = if f.kind == FaultKind::ControllerKill {
            (
                "KILL",
                "the tests running are filed incomplete (controller lost); a new controller connects",
            )
        } else {
            (
                "STOP",
                "the hang is noticed (100 ms of silence): the tests running are filed incomplete, the frozen controller is killed and a new one connects",
            )
        };
        self.fault(
            f,
            n,
            &affected,
            json!({ "signal": signal, "pid": pid }),
            expected,
        );
        let began = Instant::now();
        if let Err(e) = crate::send_signal(pid, signal) {
            self.journal.violation(e);
            return;
        }
        // kill(1) is a process of its own: on a loaded machine the signal lands anywhere
        // between the fault's entry and this moment (seconds apart, seen once in 2 hours).
        let signalled = wall_ms();
        let noticed = self.wait_until(RECOVERY, |s| {
            s.controller()
                .is_some_and(|(connected, p)| !connected || p != Some(pid))
        });
        let noticed_ms = ms(began);
        let replaced = self.wait_until(RECOVERY, |s| {
            s.controller()
                .is_some_and(|(connected, p)| connected && p.is_some() && p != Some(pid))
        });
        let replaced_ms = ms(began);
        let gone = self.wait_until(Duration::from_secs(10), |_| !host::alive(pid));
        self.outcome(
            f,
            n,
            json!({ "signalled_wall_ms": signalled,
                "link_down_seen_after_ms": noticed.then_some(noticed_ms),
                "replaced_after_ms": replaced.then_some(replaced_ms), "old_process_gone": gone }),
        );
        if !replaced {
            self.journal.violation(format!(
                "no new controller connected within {RECOVERY:?} of SIG{signal}"
            ));
        }
        if !gone {
            self.journal.violation(format!(
                "the controller {pid} that got SIGSTOP/SIGKILL is still there (state {:?}) after it was replaced",
                host::state(pid)
            ));
            let _ = crate::send_signal(pid, "CONT");
            let _ = crate::send_signal(pid, "KILL");
        }
    }

    fn hold_store(&mut self, f: Fault, n: usize) {
        let affected = self.running_with(WAIT_FOR_A_TEST, 1.5);
        let Some((true, Some(pid))) = self.controller() else {
            self.journal
                .violation("the controller was not connected when the store was to be held");
            return;
        };
        // 5–12 s from the seeded choice.
        let frac = (f.choice >> 16) as f64 / (1u64 << 48) as f64;
        let hold = Duration::from_millis(5000 + (7000.0 * frac) as u64);
        self.fault(
            f,
            n,
            &affected,
            json!({ "hold_ms": hold.as_millis() as u64 }),
            "the tests running go on and are filed once the store is free; the controller link stays up (the same controller throughout)",
        );
        let lock = crate::server::HeldWrite::take(&self.server);
        let began = Instant::now();
        let mut link_lost = None;
        self.wait_until(hold + Duration::from_secs(1), |s| {
            if link_lost.is_none()
                && let Some((connected, p)) = s.controller()
                && (!connected || p != Some(pid))
            {
                link_lost = Some(ms(began));
            }
            began.elapsed() >= hold
        });
        drop(lock);
        let released = Instant::now();
        let ids: Vec<i64> = affected.iter().map(|r| r.trial).collect();
        let filed = self.wait_until(RECOVERY, |s| {
            s.running()
                .is_some_and(|r| !r.iter().any(|r| ids.contains(&r.trial)))
        });
        self.outcome(
            f,
            n,
            json!({ "link_lost_after_ms": link_lost,
                "tests_hit_filed_after_ms": filed.then_some(ms(released)) }),
        );
        if let Some(at) = link_lost {
            self.journal.violation(format!(
                "the controller link was lost {at} ms into a held store (the server's stall taken for the controller's)"
            ));
        }
        if !filed {
            self.journal.violation(format!(
                "tests {ids:?} still running {RECOVERY:?} after the store was free again"
            ));
        }
    }

    fn fill_disk(&mut self, f: Fault, n: usize) {
        let affected = self.running_with(WAIT_FOR_A_TEST, 1.5);
        let Some(ballast) = &self.ballast else {
            self.journal
                .violation("the disk could not be filled: the soak has no ballast");
            return;
        };
        self.disk_full = true;
        if let Err(e) = ballast.fill() {
            self.journal.violation(e);
            self.disk_full = false;
            return;
        }
        let (room, ballast_pages) = (ballast.room().ok(), ballast.pages().ok());
        self.fault(
            f,
            n,
            &affected,
            json!({ "room_pages": room, "ballast_pages": ballast_pages }),
            "writes that need room fail with a clear error and no crash; the results of the tests that end meanwhile are filed once there is room again; nothing is lost",
        );
        // Writes that need room (long notes), while there is none.
        let note_on = affected.first().map(|r| r.trial);
        let full = note_on.map(|t| self.notes_until_refused(t));
        // Hold the disk full until the tests hit have ended (their results come meanwhile).
        let last_end = affected.iter().map(|r| r.ends_at).max().unwrap_or(0);
        let hold_ms = (last_end - wall_ms() + 2000).clamp(3000, ((TRIAL_S + 6.0) * 1000.0) as i64);
        let alive_before = self.server.proc.child.try_wait().ok().flatten().is_none();
        self.pause(Duration::from_millis(hold_ms as u64));
        let health = self.api.try_call("GET", "/api/health", None);
        if let Some(b) = &self.ballast
            && let Err(e) = b.release()
        {
            self.journal.violation(e);
        }
        self.disk_full = false;
        let released = Instant::now();
        let ids: Vec<i64> = affected.iter().map(|r| r.trial).collect();
        let filed = self.wait_until(RECOVERY, |s| {
            s.running()
                .is_some_and(|r| !r.iter().any(|r| ids.contains(&r.trial)))
        });
        let after = note_on.map(|t| self.note(t, 1));
        self.outcome(
            f,
            n,
            json!({ "held_ms": hold_ms, "write_while_full": full, "write_after": after,
                "health_while_full": health.as_ref().ok().map(|(c, _)| c),
                "server_alive": alive_before, "tests_hit_filed_after_ms": filed.then_some(ms(released)) }),
        );
        if !filed {
            self.journal.violation(format!(
                "tests {ids:?} still running {RECOVERY:?} after the disk had room again (their results came while it was full)"
            ));
        }
        if let Some(w) = &full
            && (w["status"] != 503 || !w["error"].as_str().unwrap_or("").contains("disk is full"))
        {
            self.journal.violation(format!(
                "a write on the full disk was answered {w}, not 503 \"the server's disk is full…\""
            ));
        }
        if let Some(a) = &after
            && a["status"] != 200
        {
            self.journal
                .violation(format!("a write after the disk had room again failed: {a}"));
        }
    }

    /// Notes of 2,000 characters on `trial` until one is refused (at most 40: 80 kB, more
    /// than the pages a full database has left to fill): the refusal, or the last answer.
    fn notes_until_refused(&self, trial: i64) -> Value {
        let mut answer = Value::Null;
        for i in 1..=40 {
            answer = self.note(trial, i);
            if answer["status"] != 200 {
                answer["notes_taken"] = json!(i - 1);
                break;
            }
        }
        answer
    }

    /// The soak's `i`th note on `trial`, of the most characters a note may have: its answer.
    fn note(&self, trial: i64, i: usize) -> Value {
        let text = format!("{i:>3} {}", "the soak's note. ".repeat(117));
        let text: String = text.chars().take(2000).collect();
        let answer = self.api.try_call(
            "POST",
            &format!("/api/trials/{trial}/note"),
            Some(json!({ "text": text })),
        );
        match answer {
            Ok((code, body)) => json!({ "status": code, "error": body.get("error") }),
            Err(e) => json!({ "status": null, "error": e }),
        }
    }

    fn break_station(&mut self, f: Fault, n: usize) {
        let running = self.running_with(WAIT_FOR_A_TEST, 1.5);
        let now = wall_ms();
        let candidates: Vec<&Running> =
            running.iter().filter(|r| r.ends_at - now >= 1500).collect();
        let hit = (!candidates.is_empty())
            .then(|| *candidates[(f.choice % candidates.len() as u64) as usize]);
        let station = hit.map_or((f.choice % self.stations.len() as u64) as usize, |r| {
            r.station
        });
        let affected: Vec<Running> = hit.into_iter().collect();
        // Durations from the seeded choice: 0.2–1.0 s to reload, 0.5–3 s offline.
        let frac = (f.choice >> 16) as f64 / (1u64 << 48) as f64;
        let (command, window_ms, expected) = match f.kind {
            FaultKind::StationReload => {
                let load = Duration::from_millis(200 + (800.0 * frac) as u64);
                (
                    Command::Reload { load },
                    load.as_millis() as i64,
                    "no input while the page loads: its test is stopped (stale input) and filed incomplete, or it ends first; the new page carries on",
                )
            }
            FaultKind::StationOffline => {
                let off = Duration::from_millis(500 + (2500.0 * frac) as u64);
                (
                    Command::Offline { off },
                    off.as_millis() as i64,
                    "the server notices the socket gone; the test is stopped for stale input and filed incomplete (never complete); the page reconnects",
                )
            }
            FaultKind::StationHidden => {
                let keep_input = (f.choice >> 8).is_multiple_of(2);
                let at_most = Duration::from_secs(4);
                let until = hit.map_or(now + 4000, |r| r.ends_at.min(now + 4000));
                (
                    Command::Hide {
                        at_most,
                        keep_input,
                    },
                    until - now,
                    if keep_input {
                        "the test is stopped and filed invalid (the display was hidden beyond the limit), never complete"
                    } else {
                        "the test is stopped (stale input, or the display hidden beyond the limit), never complete"
                    },
                )
            }
            FaultKind::StationFlood => (
                Command::Flood {
                    at_most: Duration::from_secs(8),
                },
                8000,
                "the excess is dropped and the flooding socket closed (1008); the server keeps answering; the page reconnects after 5 s",
            ),
            _ => unreachable!("station faults only"),
        };
        let keep_input = matches!(
            command,
            Command::Hide {
                keep_input: true,
                ..
            }
        );
        self.fault(
            f,
            n,
            &affected,
            json!({ "station": station, "window_ms": [now, now + window_ms], "keep_input": keep_input }),
            expected,
        );
        let began = Instant::now();
        let t0 = self.journal.elapsed().as_secs_f64();
        self.stations[station].command(command);
        let mut health_max_ms: f64 = 0.0;
        if f.kind == FaultKind::StationFlood {
            // The API while one station floods: a health request every 50 ms until the
            // server closes the flooding socket or the flood ends.
            self.wait_until(Duration::from_millis(8000), |s| {
                let asked = Instant::now();
                if s.api.try_call("GET", "/api/health", None).is_ok() {
                    health_max_ms = health_max_ms.max(ms(asked));
                }
                closed_since(s, station, t0).is_some()
            });
        } else {
            let until = Instant::now() + Duration::from_millis(window_ms.max(0) as u64);
            self.wait_until(
                Duration::from_millis(window_ms.max(0) as u64 + 1000),
                |_| Instant::now() >= until,
            );
        }
        let back = self.wait_until(RECOVERY, |s| s.stations[station].connected());
        let closed = closed_since(self, station, t0);
        self.outcome(
            f,
            n,
            json!({ "station": station, "reconnected_after_ms": back.then_some(ms(began)),
                "closed_by_server": closed, "health_max_ms": (f.kind == FaultKind::StationFlood).then_some(health_max_ms) }),
        );
        if !back {
            self.journal.violation(format!(
                "station {station} did not reconnect within {RECOVERY:?} after {}",
                f.kind.name()
            ));
        }
    }
}

/// Connections of the slow-clients fault: slow request bodies and idle ones, from one
/// address that is not the lab's (`SLOW_CLIENTS_FROM`).
const SLOW_BODIES: usize = 150;
const IDLE_CONNECTIONS: usize = 150;
/// 127.0.0.2: another machine as the server's per-address limits see it.
const SLOW_CLIENTS_FROM: u8 = 2;
/// How long the slow clients keep at it: past the server's body deadline (10 s).
const SLOW_CLIENTS_FOR: Duration = Duration::from_secs(13);

impl Soak {
    /// Another address opens slow request bodies (a login announcing 100,000 bytes, then a
    /// byte every 500 ms) and idle connections while the lab works; the dashboard's API is
    /// timed meanwhile. Every slow body must have been answered (408, or 429 past the
    /// address's connections) or closed by the end; the tests running go on.
    fn slow_clients(&mut self, f: Fault, n: usize) {
        use std::io::Write;
        let affected = self.running_with(WAIT_FOR_A_TEST, 1.5);
        let now = wall_ms();
        self.fault(
            f,
            n,
            &affected,
            json!({ "slow": SLOW_BODIES, "idle": IDLE_CONNECTIONS,
                "window_ms": [now, now + SLOW_CLIENTS_FOR.as_millis() as i64] }),
            "the lab is served meanwhile (API, stations, the tests running complete); each slow body is answered 408 within the body deadline, or 429 past the address's connections",
        );
        let from = crate::raw::loopback(SLOW_CLIENTS_FROM);
        let to = self.server.proc.addr;
        let head = crate::raw::head(
            "POST",
            "/api/login",
            &[("content-type", "application/json")],
            Some(100_000),
        );
        let mut slow: Vec<std::net::TcpStream> = Vec::new();
        let mut failed_to_open = 0;
        for _ in 0..SLOW_BODIES {
            match crate::raw::connect_from(from, to).and_then(|mut s| {
                s.write_all(head.as_bytes())?;
                s.set_nonblocking(true)?;
                Ok(s)
            }) {
                Ok(s) => slow.push(s),
                Err(_) => failed_to_open += 1,
            }
        }
        let idle: Vec<std::net::TcpStream> = (0..IDLE_CONNECTIONS)
            .filter_map(|_| crate::raw::connect_from(from, to).ok())
            .collect();
        let began = Instant::now();
        let (mut api_max_ms, mut api_failed, mut asked) = (0.0f64, 0usize, 0usize);
        let mut answered: Vec<Option<u16>> = vec![None; slow.len()];
        let mut last_byte = Instant::now();
        self.wait_until(SLOW_CLIENTS_FOR + Duration::from_secs(1), |s| {
            // A byte on every slow body still open, every 500 ms.
            if last_byte.elapsed() >= Duration::from_millis(500) {
                last_byte = Instant::now();
                for (sock, a) in slow.iter_mut().zip(&answered) {
                    if a.is_none() {
                        let _ = sock.write(b" ");
                    }
                }
            }
            for (sock, a) in slow.iter_mut().zip(answered.iter_mut()) {
                if a.is_none() {
                    *a = status_or_close(sock);
                }
            }
            let t = Instant::now();
            asked += 1;
            match s.api.try_call("GET", "/api/controller", None) {
                Ok((200, _)) => api_max_ms = api_max_ms.max(ms(t)),
                _ => api_failed += 1,
            }
            began.elapsed() >= SLOW_CLIENTS_FOR
        });
        let count = |code: u16| answered.iter().filter(|a| **a == Some(code)).count();
        let closed = answered.iter().filter(|a| **a == Some(0)).count();
        let still_open = answered.iter().filter(|a| a.is_none()).count();
        drop((slow, idle));
        self.outcome(
            f,
            n,
            json!({ "answered_408": count(408), "answered_429": count(429), "closed_unanswered": closed,
                "still_open": still_open, "failed_to_open": failed_to_open,
                "api_asked": asked, "api_failed": api_failed, "api_max_ms": api_max_ms }),
        );
        if still_open > 0 {
            self.journal.violation(format!(
                "{still_open} slow request bodies were still open {SLOW_CLIENTS_FOR:?} after they began (the body deadline is 10 s)"
            ));
        }
        if api_failed > 0 {
            self.journal.violation(format!(
                "{api_failed} of {asked} API calls failed while another address held slow bodies and idle connections"
            ));
        }
    }
}

/// The status of the answer on a non-blocking `sock` if one came (0: closed without one),
/// `None` while it is open and silent.
fn status_or_close(sock: &mut std::net::TcpStream) -> Option<u16> {
    use std::io::Read;
    let mut buf = [0u8; 512];
    match sock.read(&mut buf) {
        Ok(0) => Some(0),
        Ok(n) => Some(
            std::str::from_utf8(&buf[..n])
                .ok()
                .and_then(|t| t.get(9..12))
                .and_then(|c| c.parse().ok())
                .unwrap_or(0),
        ),
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => None,
        Err(_) => Some(0),
    }
}

/// The close code and reason the server sent station `station` since `t0` (s), if it did.
fn closed_since(s: &Soak, station: usize, t0: f64) -> Option<Value> {
    s.journal
        .of("socket.closed_by_server")
        .into_iter()
        .find(|e| e["station"] == station && e["t"].as_f64().unwrap_or(0.0) >= t0)
        .map(|e| json!({ "code": e["code"], "reason": e["reason"] }))
}

fn ms(since: Instant) -> f64 {
    (since.elapsed().as_secs_f64() * 1e4).round() / 10.0
}
