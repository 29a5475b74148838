//! The UDP port of a haptic-device host sending operator input (`serve --input-udp`).

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use bdft_protocol::rig::InputDatagram;
use tokio::net::UdpSocket;

use super::requests::MAX_INPUT_MM;
use super::state::{Shared, lock};
use crate::runtime::handoff::{InputCell, InputSample};

/// Who feeds a channel's current trial: the first sender (pinned) and its newest sequence.
struct Peer {
    cell: Arc<InputCell>,
    from: std::net::SocketAddr,
    seq: u32,
}

/// Operator input from a haptic-device host. The first datagram of a trial's channel pins
/// its sender; after that only that sender, with increasing sequence numbers, counts. A
/// spoofed or replayed datagram is rejected, so it never refreshes the input: the trial's
/// stale-input limit stops it as if the host had gone silent.
pub(super) async fn run(io: Shared, socket: UdpSocket) {
    let mut buf = [0u8; 64];
    let mut peers: HashMap<u32, Peer> = HashMap::new();
    loop {
        let Ok((n, from)) = socket.recv_from(&mut buf).await else {
            continue;
        };
        let mut g = lock(&io);
        // Bounded by the channels in use: forget the peers of finished trials.
        if peers.len() > g.channels.len() {
            peers.retain(|ch, p| g.channels.get(ch).is_some_and(|c| Arc::ptr_eq(c, &p.cell)));
        }
        let d = match InputDatagram::decode(&buf[..n]) {
            Ok(d) if d.position_mm.abs() <= MAX_INPUT_MM => d,
            _ => {
                g.rejected_datagrams += 1;
                continue;
            }
        };
        let Some(cell) = g.channels.get(&d.channel).cloned() else {
            g.rejected_datagrams += 1;
            continue;
        };
        let accepted = match peers.get_mut(&d.channel) {
            Some(p) if Arc::ptr_eq(&p.cell, &cell) => {
                let ok = p.from == from && d.seq > p.seq;
                if ok {
                    p.seq = d.seq;
                }
                ok
            }
            // A new trial on this channel: its first sender is pinned.
            _ => {
                peers.insert(
                    d.channel,
                    Peer {
                        cell: Arc::clone(&cell),
                        from,
                        seq: d.seq,
                    },
                );
                true
            }
        };
        if !accepted {
            g.rejected_datagrams += 1;
            continue;
        }
        let tick = g.rt.shared.tick.load(Ordering::Acquire);
        cell.write(InputSample {
            position_mm: d.position_mm,
            seq: u64::from(d.seq),
            arrival_tick: tick,
        });
    }
}
