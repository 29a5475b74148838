"""An independent LSL reader for the LSL test (tests/integration/lsl.rs): pylsl, which
bundles liblsl, resolves a station's signal and marker streams by their source ids, prints
"ready" once both feeds are open, then reads until the E-stop marker has arrived and the
signal stream has been quiet for a second, and prints one JSON document: each stream's
description (channels, units, the bdft metadata), every sample and marker with its
timestamp, and liblsl's clock offset to the outlets (time_correction).

Usage: lsl_client.py STATION_ID   (run only inside a network namespace)
"""

import json
import sys
import time

import pylsl


def resolve(source_id):
    found = pylsl.resolve_byprop("source_id", source_id, 1, 30.0)
    if not found:
        sys.exit(f"no stream with source_id {source_id}")
    return found[0]


def describe(info):
    desc = info.desc()
    channels = []
    ch = desc.child("channels").child("channel")
    while not ch.empty():
        channels.append([ch.child_value("label"), ch.child_value("unit")])
        ch = ch.next_sibling()
    meta = {}
    node = desc.child("bdft").first_child()
    while not node.empty():
        meta[node.name()] = node.child_value()
        node = node.next_sibling()
    return {
        "name": info.name(),
        "type": info.type(),
        "channel_count": info.channel_count(),
        "nominal_srate": info.nominal_srate(),
        "channel_format": info.channel_format(),
        "channels": channels,
        "bdft": meta,
    }


def main():
    station = sys.argv[1]
    signals = pylsl.StreamInlet(
        resolve(f"bdft-lab/station/{station}/signals"), max_buflen=60, recover=False
    )
    markers = pylsl.StreamInlet(
        resolve(f"bdft-lab/station/{station}/markers"), max_buflen=60, recover=False
    )
    signals.open_stream(30.0)
    markers.open_stream(30.0)
    out = {"signal": describe(signals.info(30.0)), "marker": describe(markers.info(30.0))}
    print("ready", flush=True)

    samples, events = [], []
    deadline = time.monotonic() + 300
    estop_seen_at = None
    last_sample_at = time.monotonic()
    while time.monotonic() < deadline:
        chunk, stamps = signals.pull_chunk(timeout=0.05, max_samples=4096)
        if stamps:
            last_sample_at = time.monotonic()
            samples.extend([t] + list(v) for t, v in zip(stamps, chunk))
        m, stamps = markers.pull_chunk(timeout=0.0)
        for t, v in zip(stamps, m):
            events.append([t, v[0]])
            if json.loads(v[0])["event"] == "e_stop":
                estop_seen_at = time.monotonic()
        now = time.monotonic()
        if estop_seen_at is not None and now - max(estop_seen_at, last_sample_at) > 1.0:
            break
    out["samples"] = samples
    out["markers"] = events
    # liblsl's estimate of the outlet's clock minus ours, from its own probes.
    out["offsets_s"] = [signals.time_correction(10.0), markers.time_correction(10.0)]
    print(json.dumps(out), flush=True)


main()
