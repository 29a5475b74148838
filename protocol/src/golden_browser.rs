//! Golden tests of the browser messages: the wire text the pages' JavaScript reads, written
//! by hand. A change that alters what a page receives or may send fails here.

use crate::browser_to_server::{
    ConsentRequest, RttPercentiles, StationMessage, SurveySubmission, TimingReport,
};
use crate::controller_to_server::LiveSample;
use crate::params::{CompensatorKind, Seat};
use crate::records::{ConsentDecision, DoneReason, StationRole, TestPhase, TrialStatus};
use crate::server_to_browser::{
    HeldTest, MonitorEvent, MonitorStation, MonitorTest, MonitorView, Phase, StationEvent,
    StationInfo, StationSocket, StationView, StopNotice, TestView,
};
use crate::study::{StudyTexts, SurveyAnswer};

fn assert_golden<T>(value: &T, text: &str)
where
    T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
{
    assert_eq!(serde_json::to_string(value).unwrap(), text);
    assert_eq!(&serde_json::from_str::<T>(text).unwrap(), value);
}

fn refused<T: serde::de::DeserializeOwned + std::fmt::Debug>(text: &str) {
    assert!(
        serde_json::from_str::<T>(text).is_err(),
        "{text} was accepted"
    );
}

fn test_view() -> TestView {
    TestView {
        trial_id: 12,
        label: "Controller 3".into(),
        phase: TestPhase::Test,
        instructions: None,
        number: 4,
        of: 10,
        duration_s: 140.0,
        seat: Seat::On,
        shake_gain: 1.0,
        target_range_mm: 40.0,
        k_bf: 0.78,
        started_at: None,
    }
}

#[test]
fn station_input_consent_survey_and_timing() {
    assert_golden(
        &StationMessage::Input {
            trial_id: 7,
            seq: 3,
            position_mm: -1.5,
        },
        r#"{"type":"input","trial_id":7,"seq":3,"position_mm":-1.5}"#,
    );
    refused::<StationMessage>(r#"{"type":"input","trial_id":7,"seq":3,"position_mm":1.0,"x":1}"#);
    assert_golden(
        &StationMessage::Display {
            trial_id: 7,
            hidden: true,
            frames: 240,
            longest_gap_ms: 16.5,
            hidden_ms: 0.0,
            inputs: 300,
        },
        r#"{"type":"display","trial_id":7,"hidden":true,"frames":240,"longest_gap_ms":16.5,"hidden_ms":0.0,"inputs":300}"#,
    );
    refused::<StationMessage>(
        r#"{"type":"display","trial_id":7,"hidden":true,"frames":240,"longest_gap_ms":16.5,"hidden_ms":0.0}"#,
    );
    assert_golden(
        &ConsentRequest {
            decision: ConsentDecision::Agreed,
        },
        r#"{"decision":"agreed"}"#,
    );
    refused::<ConsentRequest>(r#"{"decision":"maybe"}"#);
    assert_golden(
        &SurveySubmission {
            trial_id: 5,
            answer: SurveyAnswer {
                accuracy: Some(6),
                speed: Some(5),
                smoothness: None,
                controllability: Some(7),
                comment: "=smooth".into(),
            },
        },
        r#"{"trial_id":5,"accuracy":6,"speed":5,"smoothness":null,"controllability":7,"comment":"=smooth"}"#,
    );
    refused::<SurveySubmission>(
        r#"{"trial_id":5,"accuracy":6,"speed":5,"smoothness":4,"controllability":7,"bogus":1}"#,
    );
    let report = TimingReport {
        trial_id: 5,
        frames: 8400,
        long_frames: 3,
        longest_gap_ms: 40.5,
        hidden_ms: 0.0,
        input_hz: 249.5,
        rtt_ms: RttPercentiles {
            p50: 6.5,
            p95: 9.0,
            max: 31.0,
        },
    };
    assert_golden(
        &report,
        r#"{"trial_id":5,"frames":8400,"long_frames":3,"longest_gap_ms":40.5,"hidden_ms":0.0,"input_hz":249.5,"rtt_ms":{"p50":6.5,"p95":9.0,"max":31.0}}"#,
    );
    assert_eq!(report.validate(), Ok(()));
    let mut bad = report.clone();
    bad.long_frames = 9000;
    assert_eq!(
        bad.validate(),
        Err("long_frames cannot exceed frames".into())
    );
    bad = report.clone();
    bad.hidden_ms = -1.0;
    assert!(bad.validate().unwrap_err().starts_with("hidden_ms:"));
    bad = report;
    bad.rtt_ms.p95 = f64::INFINITY;
    assert!(bad.validate().unwrap_err().starts_with("rtt_ms.p95:"));
}

#[test]
fn what_a_station_shows() {
    let station = StationInfo {
        name: "Cab seat".into(),
        role: StationRole::On,
    };
    assert_golden(
        &StationView {
            phase: Phase::Waiting,
            station: station.clone(),
            stopped: None,
            texts: None,
        },
        r#"{"phase":"waiting","station":{"name":"Cab seat","role":"on"}}"#,
    );
    assert_golden(
        &StationView {
            phase: Phase::Move {
                subject: "S01".into(),
                to: Seat::Off,
            },
            station: station.clone(),
            stopped: None,
            texts: None,
        },
        r#"{"phase":"move","subject":"S01","to":"off","station":{"name":"Cab seat","role":"on"}}"#,
    );
    assert_golden(
        &StationView {
            phase: Phase::Done {
                subject: "S01".into(),
                reason: DoneReason::Finished,
            },
            station: station.clone(),
            stopped: None,
            texts: Some(StudyTexts {
                language: "de".into(),
                instructions: "i".into(),
                before_practice: "p".into(),
                before_test: "t".into(),
                ready: "r".into(),
                move_to_on: "on".into(),
                move_to_off: "off".into(),
                move_note: "m".into(),
                finished_title: "Danke!".into(),
                finished: "f".into(),
                declined_title: "dt".into(),
                declined: "d".into(),
                withdrawn_title: "wt".into(),
                withdrawn: "w".into(),
            }),
        },
        r#"{"phase":"done","subject":"S01","reason":"finished","station":{"name":"Cab seat","role":"on"},"texts":{"language":"de","instructions":"i","before_practice":"p","before_test":"t","ready":"r","move_to_on":"on","move_to_off":"off","move_note":"m","finished_title":"Danke!","finished":"f","declined_title":"dt","declined":"d","withdrawn_title":"wt","withdrawn":"w"}}"#,
    );
    assert_golden(
        &StationView {
            phase: Phase::Ready {
                subject: "S01".into(),
                test: test_view(),
            },
            station: station.clone(),
            stopped: None,
            texts: None,
        },
        r#"{"phase":"ready","subject":"S01","test":{"trial_id":12,"label":"Controller 3","phase":"test","number":4,"of":10,"duration_s":140.0,"station":"on","shake_gain":1.0,"target_range_mm":40.0,"k_bf":0.78,"started_at":null},"station":{"name":"Cab seat","role":"on"}}"#,
    );
    // After a stopped test the next one is shown with what happened; with nothing left to
    // run but a test that failed too often, the station holds (never "done").
    assert_golden(
        &StationView {
            phase: Phase::Ready {
                subject: "S01".into(),
                test: test_view(),
            },
            station: station.clone(),
            stopped: Some(StopNotice {
                label: "Controller 2".into(),
                status: TrialStatus::Invalid,
                repeated: true,
                repeated_next: false,
            }),
            texts: None,
        },
        r#"{"phase":"ready","subject":"S01","test":{"trial_id":12,"label":"Controller 3","phase":"test","number":4,"of":10,"duration_s":140.0,"station":"on","shake_gain":1.0,"target_range_mm":40.0,"k_bf":0.78,"started_at":null},"station":{"name":"Cab seat","role":"on"},"stopped":{"label":"Controller 2","status":"invalid","repeated":true}}"#,
    );
    assert_golden(
        &StationView {
            phase: Phase::Held {
                subject: "S01".into(),
                failed: Some(HeldTest {
                    trial_id: 3,
                    label: "Practice".into(),
                    phase: TestPhase::Practice,
                    attempts: 3,
                }),
            },
            station,
            stopped: None,
            texts: None,
        },
        r#"{"phase":"held","subject":"S01","failed":{"trial_id":3,"label":"Practice","phase":"practice","attempts":3},"station":{"name":"Cab seat","role":"on"}}"#,
    );
}

#[test]
fn what_the_experimenter_sees_of_a_station_names_the_compensator() {
    assert_golden(
        &MonitorView {
            phase: Phase::Running {
                subject: "S02".into(),
                test: MonitorTest {
                    test: test_view(),
                    compensator: CompensatorKind::PidNotch,
                },
            },
            station: MonitorStation {
                id: 3,
                name: "Desk".into(),
                role: StationRole::Both,
                subject_id: Some(9),
                socket: Some(StationSocket {
                    connected: false,
                    accepted: 1200,
                    dropped: 98000,
                    closed_by_server: Some("input flood".into()),
                }),
            },
        },
        r#"{"phase":"running","subject":"S02","test":{"trial_id":12,"label":"Controller 3","phase":"test","number":4,"of":10,"duration_s":140.0,"station":"on","shake_gain":1.0,"target_range_mm":40.0,"k_bf":0.78,"started_at":null,"controller":"pid-notch"},"station":{"id":3,"name":"Desk","role":"both","subject_id":9,"socket":{"connected":false,"accepted":1200,"dropped":98000,"closed_by_server":"input flood"}}}"#,
    );
}

#[test]
fn live_socket_events() {
    let sample = LiveSample {
        trial_id: 7,
        t: 0.5,
        target_mm: 10.0,
        device_mm: 16.0,
        cylinder_mm: 9.5,
        cab_accel_mm_s2: -120.0,
        input_seq: 41,
        stamp_us: 123_456,
    };
    let sample_text = r#"{"trial_id":7,"t":0.5,"target_mm":10.0,"device_mm":16.0,"cylinder_mm":9.5,"cab_accel_mm_s2":-120.0,"input_seq":41,"stamp_us":123456}"#;
    assert_golden(&StationEvent::Changed, r#"{"type":"changed"}"#);
    assert_golden(
        &StationEvent::EStop { latched: true },
        r#"{"type":"estop","latched":true}"#,
    );
    assert_golden(
        &StationEvent::EStop { latched: false },
        r#"{"type":"estop","latched":false}"#,
    );
    assert_golden(
        &StationEvent::Live { sample },
        &format!(r#"{{"type":"live","sample":{sample_text}}}"#),
    );
    assert_golden(
        &MonitorEvent::Live { sample },
        &format!(r#"{{"type":"live","sample":{sample_text}}}"#),
    );
    assert_golden(
        &MonitorEvent::Trial { trial_id: 4 },
        r#"{"type":"trial","trial_id":4}"#,
    );
    assert_golden(
        &MonitorEvent::Controller { connected: false },
        r#"{"type":"controller","connected":false}"#,
    );
    assert_golden(
        &MonitorEvent::EStop { latched: true },
        r#"{"type":"estop","latched":true}"#,
    );
}

#[test]
fn a_stop_notice_says_when_the_repeat_is_the_next_test() {
    // Only then is `repeated_next` written: a notice without it reads as before.
    assert_golden(
        &StopNotice {
            label: "Controller 2".into(),
            status: TrialStatus::Aborted,
            repeated: true,
            repeated_next: true,
        },
        r#"{"label":"Controller 2","status":"aborted","repeated":true,"repeated_next":true}"#,
    );
}
