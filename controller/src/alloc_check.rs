//! Proof that the per-tick code never allocates: a counting global allocator for the test
//! binary, counting per thread so that parallel tests do not disturb each other.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: forwarded unchanged to the system allocator (calloc, which for a large
        // block returns pages nothing has touched yet, as in the real binary).
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by this thread while running `f`.
pub fn allocations_during(f: impl FnOnce()) -> u64 {
    let before = ALLOCATIONS.with(Cell::get);
    f();
    ALLOCATIONS.with(Cell::get) - before
}

#[cfg(test)]
mod tests {
    use super::allocations_during;
    use crate::closed_loop::{ClosedLoop, Drive, LoopSetup};
    use crate::compensator::variants;
    use crate::operator::{OperatorParams, SyntheticOperator};
    use crate::params::{BodyModel, LoopParams, PlantParams, Seat};

    #[test]
    fn the_counter_sees_allocations() {
        assert!(allocations_during(|| drop(std::hint::black_box(vec![1u8; 64]))) >= 1);
    }

    /// The population's median body as a cancellation model (issue 38's generic model).
    fn generic_model() -> crate::cancellation::CancellationModel {
        let body = bdft_protocol::params::PopulationParams::default().median_body();
        crate::cancellation::CancellationModel::of_seated(&body).unwrap()
    }

    #[test]
    fn a_closed_loop_tick_never_allocates() {
        let plant = PlantParams::default();
        for name in variants::names() {
            for body in [
                BodyModel::default(),
                BodyModel::SingleResonance {
                    k_h: 0.5,
                    f_hz: 5.0,
                    zeta: 0.3,
                },
                crate::model::SEATED_FOR_TESTS,
            ] {
                let setup = LoopSetup {
                    compensator: variants::variant(&name, &plant, 1e-3).unwrap(),
                    plant,
                    body,
                    loop_params: LoopParams::default(),
                    seat: Seat::On,
                };
                // Without and with model-based cancellation (a bound that trips within the
                // run, so the tripped path runs too).
                for limit_mm in [None, Some(0.05)] {
                    let mut lp = ClosedLoop::new(&setup, 1).unwrap();
                    lp.set_canceller(limit_mm.map(|limit_mm| {
                        crate::cancellation::Canceller::new(
                            &crate::cancellation::CancellationModel {
                                phase_lag_deg: 30.0,
                                limit_mm,
                                ..generic_model()
                            },
                            1e-3,
                        )
                        .unwrap()
                    }));
                    let mut op =
                        SyntheticOperator::new(OperatorParams::default(), 1e-3, 0.6, 1).unwrap();
                    let n = allocations_during(|| {
                        for k in 0..5_000 {
                            let target = if k < 2_500 { 20.0 } else { -30.0 };
                            let p_h = op.step(target, lp.last_measurement().y, lp.felt_accel());
                            lp.set_grip(op.grip());
                            std::hint::black_box(lp.tick(Drive::Hand(p_h)));
                        }
                        lp.reset();
                    });
                    assert_eq!(
                        n, 0,
                        "{name} (cancelling: {limit_mm:?}) allocated {n} times in 5,000 ticks"
                    );
                }
            }
        }
    }

    #[test]
    fn an_identification_tick_never_allocates() {
        use crate::identification::Multisine;
        use crate::operator::IdentificationTask;
        use crate::runner::{HandSource, TrialRunner};
        use crate::signals::Signal;
        use bdft_protocol::identification::MultisineSpec;

        let plant = PlantParams::default();
        let spec = MultisineSpec::default();
        let dt = 1e-3;
        for task in IdentificationTask::ALL {
            for synthetic in [true, false] {
                let setup = LoopSetup {
                    compensator: variants::variant("pid", &plant, dt).unwrap(),
                    plant,
                    body: crate::model::SEATED_FOR_TESTS,
                    loop_params: LoopParams::default(),
                    seat: Seat::On,
                };
                let hand = if synthetic {
                    HandSource::Synthetic(
                        SyntheticOperator::new(OperatorParams::default(), dt, 0.6, 1)
                            .unwrap()
                            .holding(task),
                    )
                } else {
                    HandSource::External
                };
                let mut runner = TrialRunner::new(
                    Signal::Multisine(Multisine::new(&spec, dt).unwrap()),
                    ClosedLoop::new(&setup, 1).unwrap(),
                    hand,
                    dt,
                    spec.duration_s(),
                )
                .with_interlock(6000.0);
                // Across a period boundary of the table.
                let n = allocations_during(|| {
                    for k in 0..12_000 {
                        std::hint::black_box(runner.tick((k % 7) as f64));
                    }
                });
                assert_eq!(n, 0, "{task:?}, synthetic {synthetic}: {n} allocations");
            }
        }
    }
}
