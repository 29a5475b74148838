//! What a station's LSL streams say about themselves, and how far discovery reaches.

use bdft_protocol::trial::{RECORD_CHANNELS, record_channel};
use labstream_net::StreamInfo;
use labstream_wire::Format;

/// The record channels a station's signal stream carries, in its channel order.
pub const SIGNAL_CHANNELS: [&str; 5] = [
    "target_mm",
    "device_mm",
    "cyl_pos_mm",
    "cab_accel_mm_s2",
    "valve_cmd",
];

/// Where each of [`SIGNAL_CHANNELS`] is in a record row.
pub fn signal_columns() -> [usize; SIGNAL_CHANNELS.len()] {
    SIGNAL_CHANNELS.map(|name| record_channel(name).expect("a record channel"))
}

/// The loop's rate: a signal stream carries every tick of a test.
pub const SIGNAL_RATE_HZ: f64 = 1000.0;

/// How far LSL discovery answers (liblsl's `ResolveScope`): the machine (loopback only, the
/// default), the link or the site.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Scope {
    #[default]
    Machine,
    Link,
    Site,
}

impl Scope {
    pub fn as_str(self) -> &'static str {
        match self {
            Scope::Machine => "machine",
            Scope::Link => "link",
            Scope::Site => "site",
        }
    }

    /// Sets the process's LSL configuration; before the first stream is published (it is
    /// read once, as liblsl reads `lsl_api.cfg`). Machine scope joins no multicast group and
    /// sends nothing beyond this host.
    pub fn configure(self) {
        labstream_net::config::set_content(&format!(
            "[multicast]\nResolveScope = {}\n",
            self.as_str()
        ));
    }
}

/// Who a station's streams are about: put in each stream's description, as LSL readers
/// (LabRecorder, pylsl) show and store it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StreamTags {
    /// The station's id and name.
    pub station_id: i64,
    pub station: String,
    /// The study's id and name.
    pub study_id: i64,
    pub study: String,
    /// The pseudonymous code of the subject at the station.
    pub subject: String,
}

/// The station's 1 kHz signal stream: float32, the channels of [`SIGNAL_CHANNELS`] with
/// their units from the record's codebook.
pub fn signal_stream(tags: &StreamTags) -> StreamInfo {
    let mut info = StreamInfo::new(
        &format!("bdft {} signals", tags.station),
        "Motion",
        SIGNAL_CHANNELS.len() as u32,
        Format::Float32,
        SIGNAL_RATE_HZ,
    );
    info.source_id = format!("bdft-lab/station/{}/signals", tags.station_id);
    let channels = info.desc.append_child("channels");
    for column in signal_columns() {
        let c = &RECORD_CHANNELS[column];
        let ch = channels.append_child("channel");
        ch.append_child_value("label", c.name);
        ch.append_child_value("unit", c.unit);
        ch.append_child_value("type", c.meaning);
    }
    describe(&mut info, tags);
    info
}

/// The station's marker stream: one string per event, irregular.
pub fn marker_stream(tags: &StreamTags) -> StreamInfo {
    let mut info = StreamInfo::new(
        &format!("bdft {} markers", tags.station),
        "Markers",
        1,
        Format::String,
        0.0,
    );
    info.source_id = format!("bdft-lab/station/{}/markers", tags.station_id);
    describe(&mut info, tags);
    info
}

fn describe(info: &mut StreamInfo, tags: &StreamTags) {
    let node = info.desc.append_child("bdft");
    node.append_child_value("study_id", &tags.study_id.to_string());
    node.append_child_value("study", &tags.study);
    node.append_child_value("station_id", &tags.station_id.to_string());
    node.append_child_value("station", &tags.station);
    node.append_child_value("subject", &tags.subject);
    node.append_child_value("software", concat!("bdft-lab ", env!("CARGO_PKG_VERSION")));
}

/// Seconds on the LSL clock (CLOCK_MONOTONIC, as liblsl's `local_clock`) of a loop time in
/// nanoseconds (the loop's clock is the same one).
pub fn lsl_seconds(ns: u64) -> f64 {
    ns as f64 * 1e-9
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_signal_channels_are_record_channels_with_their_units() {
        let units: Vec<&str> = signal_columns()
            .iter()
            .map(|&c| RECORD_CHANNELS[c].unit)
            .collect();
        assert_eq!(units, ["mm", "mm", "mm", "mm/s²", "1"]);
    }

    #[test]
    fn the_loop_clock_is_the_lsl_clock() {
        let ours = lsl_seconds(crate::runtime::os::now_ns());
        let theirs = labstream_net::clock();
        assert!((theirs - ours).abs() < 0.01, "{ours} vs {theirs}");
    }
}
