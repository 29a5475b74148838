//! E-stop delivery latency of the real controller process, on the E-stop's own connection
//! and (for comparison) on the control connection, with the control connection idle and
//! flooded with operator input as fast as a socket takes it. Each press is timed from
//! writing the E-stop to reading the controller's confirmation.
//!
//! `cargo build --release -p bdft-controller && cargo bench -p bdft-tests --bench estop_latency`

use std::io::Write;
use std::net::TcpStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bdft_protocol::controller_to_server::ControllerToServer;
use bdft_protocol::framing::encode;
use bdft_protocol::link_auth::LinkRole;
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::trial::FaultKind;
use bdft_tests::controller_link::{Link, Proc, input_flood_batch};

/// Presses on `on`, writing through `writer` when the connection is shared with a flood
/// (frames must not interleave: the press waits for the batch being written, as an E-stop
/// behind queued input would).
fn press(on: &mut Link, writer: Option<&Mutex<TcpStream>>) -> Duration {
    let pressed = Instant::now();
    match writer {
        Some(w) => w
            .lock()
            .unwrap()
            .write_all(&encode(&ServerToController::EStop {}).unwrap())
            .unwrap(),
        None => on.send(&ServerToController::EStop {}),
    }
    loop {
        if let ControllerToServer::Fault {
            kind: FaultKind::EStop,
            trial_id: None,
            ..
        } = on.recv()
        {
            return pressed.elapsed();
        }
    }
}

type Flood = (
    Arc<AtomicBool>,
    Arc<Mutex<TcpStream>>,
    std::thread::JoinHandle<u64>,
);

/// Floods `link`'s socket with operator input until the returned flag is set; the socket's
/// writer is shared behind the mutex.
fn flood(link: &Link) -> Flood {
    let to = Arc::new(Mutex::new(link.stream_clone()));
    let writer = Arc::clone(&to);
    let stop = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&stop);
    let batch = input_flood_batch(1, 1000);
    let t = std::thread::spawn(move || {
        let mut sent = 0;
        while !flag.load(Ordering::Relaxed) && to.lock().unwrap().write_all(&batch).is_ok() {
            sent += 1000;
        }
        sent
    });
    (stop, writer, t)
}

fn report(name: &str, mut took: Vec<Duration>) {
    took.sort();
    let q = |p: f64| took[((took.len() - 1) as f64 * p).round() as usize].as_secs_f64() * 1e3;
    println!(
        "{name:<44} n={:<4} p50 {:>8.3} ms  p99 {:>8.3} ms  max {:>8.3} ms",
        took.len(),
        q(0.5),
        q(0.99),
        q(1.0)
    );
}

fn scenario(name: &str, presses: usize, own_path: bool, flooded: bool) {
    let ctl = Proc::controller(&[]);
    let (mut control, _) = Link::connect(&ctl);
    let (mut path, _) = Link::hello_as(ctl.addr, &ctl.key, LinkRole::EStop);
    let flooding = flooded.then(|| flood(&control));
    if flooded {
        // Let the socket buffers fill.
        std::thread::sleep(Duration::from_millis(500));
    }
    let writer = flooding
        .as_ref()
        .filter(|_| !own_path)
        .map(|f| Arc::clone(&f.1));
    let on = if own_path { &mut path } else { &mut control };
    let took: Vec<Duration> = (0..presses).map(|_| press(on, writer.as_deref())).collect();
    if let Some((stop, _, t)) = flooding {
        stop.store(true, Ordering::Relaxed);
        drop(ctl);
        let sent = t.join().unwrap();
        println!("  (flood: {sent} inputs written)");
    }
    report(name, took);
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    scenario("e-stop connection, control idle", 500, true, false);
    scenario("e-stop connection, control flooded", 500, true, true);
    scenario("control connection, idle", 500, false, false);
    scenario("control connection, flooded", 30, false, true);
}
