//! Golden tests: the wire text of each kind of message, written by hand from the documented
//! format (docs/protocol.md). A change that alters what goes on the wire fails here.

use crate::PROTOCOL_VERSION;
use crate::controller_to_server::{ControllerToServer, LiveSample, RecordChunk, TrialResult};
use crate::framing::encode;
use crate::params::{CompensatorSpec, NotchParams, OperatorParams, PidParams, Seat};
use crate::server_to_controller::{ServerToController, StartTrial};
use crate::trial::{
    FaultKind, InputSource, Metrics, Outcome, Percentiles, TargetSpec, TimingSummary,
};

fn decode<T: serde::de::DeserializeOwned>(payload: &[u8]) -> serde_json::Result<T> {
    serde_json::from_slice(payload)
}

fn assert_golden<T>(value: &T, text: &str)
where
    T: serde::Serialize + serde::de::DeserializeOwned + PartialEq + std::fmt::Debug,
{
    let frame = encode(value).unwrap();
    assert_eq!(std::str::from_utf8(&frame[4..]).unwrap(), text);
    let len = u32::from_be_bytes(frame[..4].try_into().unwrap()) as usize;
    assert_eq!(len, text.len());
    assert_eq!(&decode::<T>(text.as_bytes()).unwrap(), value);
}

#[test]
fn hello_and_small_messages() {
    assert_golden(
        &ServerToController::Hello {
            protocol_version: PROTOCOL_VERSION,
            client: "bdft-server".into(),
            role: crate::link_auth::LinkRole::EStop,
            nonce: crate::link_auth::Bytes32([0xab; 32]),
            proof: crate::link_auth::Bytes32([0x01; 32]),
        },
        &format!(
            r#"{{"type":"hello","protocol_version":3,"client":"bdft-server","role":"e_stop","nonce":"{}","proof":"{}"}}"#,
            "ab".repeat(32),
            "01".repeat(32)
        ),
    );
    assert_golden(
        &crate::controller_to_server::ControllerToServer::Challenge {
            protocol_version: PROTOCOL_VERSION,
            nonce: crate::link_auth::Bytes32([0xff; 32]),
        },
        &format!(
            r#"{{"type":"challenge","protocol_version":3,"nonce":"{}"}}"#,
            "ff".repeat(32)
        ),
    );
    assert_golden(
        &ServerToController::OperatorInput {
            trial_id: 7,
            seq: 42,
            position_mm: -3.5,
        },
        r#"{"type":"operator_input","trial_id":7,"seq":42,"position_mm":-3.5}"#,
    );
    assert_golden(&ServerToController::EStop {}, r#"{"type":"e_stop"}"#);
    assert_golden(
        &ServerToController::ResetEStop {},
        r#"{"type":"reset_e_stop"}"#,
    );
    assert_golden(&ServerToController::Status {}, r#"{"type":"status"}"#);
    // A message without fields refuses unknown ones too, as every other does.
    for text in [
        r#"{"type":"status","x":1}"#,
        r#"{"type":"e_stop","now":true}"#,
        r#"{"type":"reset_e_stop","all":1}"#,
    ] {
        assert!(
            decode::<ServerToController>(text.as_bytes()).is_err(),
            "{text}"
        );
    }
    assert_golden(
        &ServerToController::Step { ticks: 10 },
        r#"{"type":"step","ticks":10}"#,
    );
    assert_golden(
        &ServerToController::LslStation(Box::new(crate::server_to_controller::LslStation {
            station_id: 2,
            station: "cab".into(),
            study_id: 1,
            study: "pilot".into(),
            subject: "S001".into(),
            trial_id: Some(9),
        })),
        r#"{"type":"lsl_station","station_id":2,"station":"cab","study_id":1,"study":"pilot","subject":"S001","trial_id":9}"#,
    );
    assert_golden(
        &ControllerToServer::Fault {
            trial_id: Some(7),
            kind: FaultKind::StaleInput,
            message: "no input for 100 ms".into(),
        },
        r#"{"type":"fault","trial_id":7,"kind":"stale-input","message":"no input for 100 ms"}"#,
    );
    assert_golden(
        &ControllerToServer::Live(LiveSample {
            trial_id: 7,
            t: 0.5,
            target_mm: 10.0,
            device_mm: 16.0,
            cylinder_mm: 9.5,
            cab_accel_mm_s2: -120.0,
            input_seq: 41,
            stamp_us: 123_456,
        }),
        r#"{"type":"live","trial_id":7,"t":0.5,"target_mm":10.0,"device_mm":16.0,"cylinder_mm":9.5,"cab_accel_mm_s2":-120.0,"input_seq":41,"stamp_us":123456}"#,
    );
}

#[test]
fn start_trial_with_defaults_filled_in() {
    let text = r#"{"type":"start_trial","trial_id":3,"compensator":{"kind":"pid-notch","pid":{"kp":0.5,"ti":0.15,"td":0.04,"n":10.0},"notch":{"f_hz":5.1,"zeta":0.3}},"station":"on","k_bf":0.78,"target":{"kind":"steps","interval_s":2.0,"levels_mm":[10.0,-5.0]},"duration_s":4.0,"input":{"kind":"server"}}"#;
    let msg: ServerToController = decode(text.as_bytes()).unwrap();
    let ServerToController::StartTrial(st) = &msg else {
        panic!("{msg:?}")
    };
    assert_eq!(
        st.compensator,
        CompensatorSpec::PidNotch {
            pid: PidParams {
                kp: 0.5,
                ti: 0.15,
                td: 0.04,
                n: 10.0
            },
            notch: NotchParams::default()
        }
    );
    assert_eq!(st.seat, Seat::On);
    assert_eq!(st.live_rate_hz, 100.0);
    assert_eq!(st.stale_input_ms, 100.0);
    assert_eq!(st.plant.k_vc, 22.0);
    st.validate().unwrap();
    let again: ServerToController = decode(&encode(&msg).unwrap()[4..]).unwrap();
    assert_eq!(again, msg);
}

#[test]
fn start_trial_validation_names_the_bad_field() {
    let st = StartTrial {
        trial_id: 1,
        compensator: CompensatorSpec::Pid {
            pid: PidParams {
                kp: 0.5,
                ti: 0.15,
                td: 0.04,
                n: 10.0,
            },
        },
        seat: Seat::Off,
        k_bf: f64::NAN,
        target: TargetSpec::Steps {
            interval_s: 2.0,
            levels_mm: vec![1.0],
        },
        duration_s: 10.0,
        input: InputSource::Synthetic {
            operator: OperatorParams::default(),
            seed: 1,
        },
        plant: Default::default(),
        body: Default::default(),
        noise_seed: 0,
        live_rate_hz: 100.0,
        stale_input_ms: 100.0,
        max_cab_rms_mm_s2: crate::server_to_controller::DEFAULT_MAX_CAB_RMS_MM_S2,
        exposure_allowance: None,
        cancellation: None,
        condition: Default::default(),
    };
    assert!(st.validate().unwrap_err().to_string().contains("k_bf"));
    let st = StartTrial {
        k_bf: 0.6,
        duration_s: 1e9,
        ..st
    };
    assert!(
        st.validate()
            .unwrap_err()
            .to_string()
            .contains("duration_s")
    );
    let st = StartTrial {
        duration_s: 10.0,
        target: TargetSpec::Steps {
            interval_s: 2.0,
            levels_mm: vec![],
        },
        ..st
    };
    assert!(st.validate().unwrap_err().to_string().contains("levels_mm"));
    let sampled = TargetSpec::Sampled {
        sample_rate_hz: 100.0,
        samples_mm: vec![0.0, 1.5],
    };
    assert_golden(
        &sampled,
        r#"{"kind":"sampled","sample_rate_hz":100.0,"samples_mm":[0.0,1.5]}"#,
    );
    // A sample out of range, and too few samples.
    for samples_mm in [vec![0.0, f64::INFINITY], vec![0.0]] {
        let st = StartTrial {
            target: TargetSpec::Sampled {
                sample_rate_hz: 100.0,
                samples_mm,
            },
            ..st.clone()
        };
        let err = st.validate().unwrap_err().to_string();
        assert!(err.contains("samples_mm"), "{err}");
    }
    let identification = TargetSpec::Identification {
        excitation: crate::identification::MultisineSpec::default(),
        task: crate::identification::IdentificationTask::HoldStill,
    };
    assert_golden(
        &identification,
        r#"{"kind":"identification","excitation":{"f_min_hz":0.5,"f_max_hz":8.0,"lines":20,"period_s":10.0,"periods":6,"transient_periods":1,"rms_mm":6.0,"seed":0},"task":"hold-still"}"#,
    );
    assert_eq!(identification.kind(), "identification");
    // The trial lasts the multisine's periods; a bad multisine names its field.
    let st = StartTrial {
        target: identification.clone(),
        duration_s: 70.0,
        ..st
    };
    st.validate().unwrap();
    let err = StartTrial {
        duration_s: 60.0,
        ..st.clone()
    }
    .validate()
    .unwrap_err()
    .to_string();
    assert!(err.contains("duration_s") && err.contains("70 s"), "{err}");
    let err = StartTrial {
        target: TargetSpec::Identification {
            excitation: crate::identification::MultisineSpec {
                lines: 2,
                ..Default::default()
            },
            task: crate::identification::IdentificationTask::Relax,
        },
        ..st
    }
    .validate()
    .unwrap_err()
    .to_string();
    assert!(err.contains("multisine.lines"), "{err}");
}

/// Cancellation on the wire: left out when there is none (older messages unchanged), its
/// defaults filled in, and refused naming it out of range, at the desk and in the
/// identification test.
#[test]
fn cancellation_on_the_wire_and_where_it_is_refused() {
    use crate::cancellation::CancellationModel;
    let model: CancellationModel = serde_json::from_str(
        r#"{"k_h":0.5,"torso_f_hz":1.1,"torso_zeta":0.4,"arm_f_hz":2.0,"arm_zeta":0.35}"#,
    )
    .unwrap();
    assert_golden(
        &model,
        r#"{"k_h":0.5,"torso_f_hz":1.1,"torso_zeta":0.4,"arm_f_hz":2.0,"arm_zeta":0.35,"gain":1.0,"phase_lag_deg":0.0,"phase_ref_hz":2.0,"limit_mm":100.0}"#,
    );
    let ServerToController::StartTrial(st) = serde_json::from_str::<ServerToController>(
        r#"{"type":"start_trial","trial_id":7,"compensator":{"kind":"pid","pid":{"kp":0.5,"ti":0.15,"td":0.04,"n":10.0}},"station":"on","k_bf":0.78,"target":{"kind":"steps","interval_s":2.0,"levels_mm":[1.0]},"duration_s":10.0,"input":{"kind":"server"}}"#,
    )
    .unwrap() else {
        panic!("not a start_trial")
    };
    assert_eq!(st.cancellation, None);
    assert!(!serde_json::to_string(&st).unwrap().contains("cancellation"));
    let on = StartTrial {
        cancellation: Some(model),
        ..*st
    };
    on.validate().unwrap();
    let err = |st: StartTrial| st.validate().unwrap_err().to_string();
    assert!(
        err(StartTrial {
            cancellation: Some(CancellationModel { gain: 5.0, ..model }),
            ..on.clone()
        })
        .starts_with("cancellation.gain = 5 is out of range"),
    );
    assert_eq!(
        err(StartTrial {
            seat: Seat::Off,
            ..on.clone()
        }),
        "cancellation: at the desk no body rides: cancellation is for tests on the machine"
    );
    let e = err(StartTrial {
        target: TargetSpec::Identification {
            excitation: crate::identification::MultisineSpec::default(),
            task: crate::identification::IdentificationTask::HoldStill,
        },
        duration_s: 70.0,
        ..on
    });
    assert!(
        e.starts_with("cancellation: the identification test"),
        "{e}"
    );
    assert!(serde_json::from_str::<CancellationModel>(r#"{"k_h":0.5}"#).is_err());
}

#[test]
fn trial_result_and_record_chunk() {
    let result = ControllerToServer::TrialResult(Box::new(TrialResult {
        trial_id: 3,
        outcome: Outcome::Faulted {
            fault: FaultKind::EStop,
            message: "e-stop".into(),
        },
        metrics: Metrics {
            ticks: 2,
            mse_tracking_mm2: 1.5,
            ms_cab_accel: 4.0,
        },
        timing: TimingSummary {
            ticks: 2,
            overruns: 0,
            wake_latency_us: Percentiles {
                p50: 1.0,
                p99: 2.0,
                max: 3.0,
            },
            compute_us: Percentiles {
                p50: 0.5,
                p99: 0.5,
                max: 0.5,
            },
        },
        dt: 0.001,
        record_chunks: 1,
        exposure: None,
        cancellation_off_at_s: None,
        adaptation: None,
    }));
    assert_golden(
        &result,
        r#"{"type":"trial_result","trial_id":3,"outcome":{"status":"faulted","fault":"e-stop","message":"e-stop"},"metrics":{"ticks":2,"mse_tracking_mm2":1.5,"ms_cab_accel":4.0},"timing":{"ticks":2,"overruns":0,"wake_latency_us":{"p50":1.0,"p99":2.0,"max":3.0},"compute_us":{"p50":0.5,"p99":0.5,"max":0.5}},"dt":0.001,"record_chunks":1}"#,
    );
    assert_golden(
        &ControllerToServer::RecordChunk(RecordChunk {
            trial_id: 3,
            index: 0,
            start_tick: 0,
            channels: vec![vec![1.5, -2.0]],
        }),
        r#"{"type":"record_chunk","trial_id":3,"index":0,"start_tick":0,"channels":[[1.5,-2.0]]}"#,
    );
    assert_golden(&Outcome::Complete, r#"{"status":"complete"}"#);
    // An adaptive design's account of the test rides with its result.
    let ControllerToServer::TrialResult(mut adapted) = result else {
        unreachable!()
    };
    adapted.adaptation = Some(crate::params::AdaptationStatus {
        f_hz: Some(3.25),
        zeta: Some(0.05),
        confident: true,
        confident_since_s: Some(0.5),
        ratio: 0.81,
        retunes: 2,
        fallbacks: 1,
    });
    assert_golden(
        &ControllerToServer::TrialResult(adapted),
        r#"{"type":"trial_result","trial_id":3,"outcome":{"status":"faulted","fault":"e-stop","message":"e-stop"},"metrics":{"ticks":2,"mse_tracking_mm2":1.5,"ms_cab_accel":4.0},"timing":{"ticks":2,"overruns":0,"wake_latency_us":{"p50":1.0,"p99":2.0,"max":3.0},"compute_us":{"p50":0.5,"p99":0.5,"max":0.5}},"dt":0.001,"record_chunks":1,"adaptation":{"f_hz":3.25,"zeta":0.05,"confident":true,"confident_since_s":0.5,"ratio":0.81,"retunes":2,"fallbacks":1}}"#,
    );
}

#[test]
fn unknown_messages_and_fields_are_refused() {
    assert!(decode::<ServerToController>(br#"{"type":"launch"}"#).is_err());
    assert!(decode::<ServerToController>(br#"{"type":"heartbeat","seq":1,"extra":2}"#).is_err());
}

#[test]
fn the_exposure_guard_on_the_wire() {
    use crate::exposure::{ExposureAllowance, TrialExposure};
    assert_golden(
        &ExposureAllowance {
            energy_m2_s3: 7200.0,
            vdv4_m4_s7: 6857.5,
        },
        r#"{"energy_m2_s3":7200.0,"vdv4_m4_s7":6857.5}"#,
    );
    assert_golden(
        &TrialExposure {
            aw_m_s2: 0.5,
            vdv_m_s175: 2.25,
            duration_s: 140.0,
        },
        r#"{"aw_m_s2":0.5,"vdv_m_s175":2.25,"duration_s":140.0}"#,
    );
    assert_golden(&FaultKind::ExposureBudget, r#""exposure-budget""#);
    // A negative allowance is refused at the boundary, naming it.
    let bad = ExposureAllowance {
        energy_m2_s3: -1.0,
        vdv4_m4_s7: 1.0,
    };
    assert!(
        bad.validate()
            .unwrap_err()
            .to_string()
            .contains("exposure_allowance.energy_m2_s3")
    );
}
