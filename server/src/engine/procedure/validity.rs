//! Whether a person's running test is valid: the subject must see the display. The station
//! page reports its display's health on its socket (hidden or not, frames, the longest gap
//! between frames, time hidden); a test whose display was hidden or stalled beyond the
//! study's limits — or whose station stopped reporting, since a hidden tab's timers are
//! throttled and silence means hidden or stalled — is stopped at once and filed invalid with
//! the reason. Synthetic subjects have no display and are exempt.

use std::time::{Duration, Instant};

use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::study::StudyParams;
use sqlx::AnyPool;

use super::trials::site_of_trial;
use crate::engine::machine::controller_link::ControllerEvent;
use crate::engine::machine::sites::Sites;
use crate::error::{AppError, Result};
use crate::store::audit::Reason;
use crate::store::{self, Change};

/// How long a test that just started may go without a display report: the page hears of
/// the start on its socket and reads its state before it draws (a request on a loaded
/// machine), so its first report comes later than the next ones.
pub const START_GRACE: Duration = Duration::from_secs(3);

/// A study's display limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisplayLimits {
    pub max_hidden_ms: f64,
    pub max_frame_gap_ms: f64,
}

impl DisplayLimits {
    pub fn of(params: &StudyParams) -> Self {
        Self {
            max_hidden_ms: params.max_hidden_ms,
            max_frame_gap_ms: params.max_frame_gap_ms,
        }
    }
}

/// One display report, as the page sends it (ms since the test started on the page).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisplayReport {
    pub hidden: bool,
    pub longest_gap_ms: f64,
    pub hidden_ms: f64,
}

/// The display watch of one running test. Time is passed in.
#[derive(Debug)]
pub struct DisplayWatch {
    pub trial_id: i64,
    limits: DisplayLimits,
    /// The last report, or the test's start (with [`START_GRACE`] added).
    heard_at: Instant,
    /// Hidden time reported, and since when the page has said it is hidden.
    hidden_ms: f64,
    hidden_since: Option<Instant>,
}

impl DisplayWatch {
    pub fn new(trial_id: i64, limits: DisplayLimits, now: Instant) -> Self {
        Self {
            trial_id,
            limits,
            heard_at: now + START_GRACE,
            hidden_ms: 0.0,
            hidden_since: None,
        }
    }

    /// A report arrived at `now`: the verdict when it shows the display beyond a limit.
    pub fn report(&mut self, now: Instant, r: DisplayReport) -> Option<String> {
        self.heard_at = self.heard_at.max(now);
        self.hidden_ms = self.hidden_ms.max(r.hidden_ms);
        self.hidden_since = match (r.hidden, self.hidden_since) {
            (true, Some(since)) => Some(since),
            (true, None) => Some(now),
            (false, _) => None,
        };
        if r.longest_gap_ms > self.limits.max_frame_gap_ms {
            return Some(format!(
                "the display drew no frame for {:.0} ms (limit {:.0} ms)",
                r.longest_gap_ms, self.limits.max_frame_gap_ms
            ));
        }
        self.check(now)
    }

    /// The verdict at `now` without a report: hidden for too long in all, or silent.
    pub fn check(&self, now: Instant) -> Option<String> {
        let ms = |d: Duration| d.as_secs_f64() * 1e3;
        let hidden = self.hidden_ms
            + self
                .hidden_since
                .map_or(0.0, |since| ms(now.saturating_duration_since(since)));
        if hidden > self.limits.max_hidden_ms {
            return Some(format!(
                "the display was hidden for {hidden:.0} ms (limit {:.0} ms)",
                self.limits.max_hidden_ms
            ));
        }
        let silent = ms(now.saturating_duration_since(self.heard_at));
        if silent > self.limits.max_frame_gap_ms {
            return Some(format!(
                "the station sent no display report for {silent:.0} ms (limit {:.0} ms): its display was hidden or stalled",
                self.limits.max_frame_gap_ms
            ));
        }
        None
    }
}

/// The display limits of a running test when it is a person's (a synthetic subject's has
/// none).
pub async fn limits_of(pool: &AnyPool, trial_id: i64) -> Result<Option<DisplayLimits>> {
    let trial = store::trials::get(pool, trial_id).await?;
    let subject = store::subjects::get(pool, trial.subject_id).await?;
    if subject.synthetic {
        return Ok(None);
    }
    let study = store::studies::get(pool, subject.study_id).await?;
    Ok(Some(DisplayLimits::of(&study.params)))
}

/// Files the running trial invalid with `reason` and stops it on its site's controller at
/// once. Its result (or a lost link) then files it invalid. `false` when it was no longer
/// running.
pub async fn invalidate(
    pool: &AnyPool,
    sites: &Sites,
    actor: &str,
    trial_id: i64,
    reason: &str,
) -> Result<bool> {
    let mut change = Change::begin(pool, actor).await?;
    if !store::trials::mark_invalid(change.db(), trial_id, reason).await? {
        return Ok(false);
    }
    change
        .commit(
            "trial.invalid",
            Some(format!("trial:{trial_id}")),
            Reason { reason },
        )
        .await?;
    // Marked first, so that whatever the controller answers the trial is filed invalid; a
    // controller that cannot be told has lost its link, which files the trial too.
    let link = store::trials::get(pool, trial_id)
        .await
        .and_then(|t| site_of_trial(sites, &t));
    let sent = link.and_then(|link| {
        link.send(&ServerToController::AbortTrial {
            trial_id: trial_id as u64,
            reason: format!("invalid: {reason}"),
        })
        .map_err(AppError::Unavailable)
    });
    if let Err(why) = sent {
        tracing::warn!(
            trial = trial_id,
            "stopping an invalid trial: {}",
            why.describe()
        );
    }
    sites.emit(ControllerEvent::TrialChanged { trial_id });
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;

    const LIMITS: DisplayLimits = DisplayLimits {
        max_hidden_ms: 500.0,
        max_frame_gap_ms: 1000.0,
    };

    fn report(hidden: bool, longest_gap_ms: f64, hidden_ms: f64) -> DisplayReport {
        DisplayReport {
            hidden,
            longest_gap_ms,
            hidden_ms,
        }
    }

    #[test]
    fn a_visible_display_that_keeps_reporting_is_valid() {
        let t0 = Instant::now();
        let mut w = DisplayWatch::new(1, LIMITS, t0);
        for i in 0..100 {
            let now = t0 + Duration::from_millis(250 * i);
            assert_eq!(w.report(now, report(false, 40.0, 120.0)), None);
            assert_eq!(w.check(now + Duration::from_millis(900)), None);
        }
    }

    #[test]
    fn hidden_time_reported_or_running_beyond_the_limit_is_invalid() {
        let t0 = Instant::now();
        let mut w = DisplayWatch::new(1, LIMITS, t0);
        let v = w.report(t0, report(false, 16.0, 600.0)).unwrap();
        assert!(v.contains("hidden for 600 ms (limit 500 ms)"), "{v}");
        // Hidden now: the watch counts on without another report.
        let mut w = DisplayWatch::new(1, LIMITS, t0);
        assert_eq!(w.report(t0, report(true, 16.0, 100.0)), None);
        assert_eq!(w.check(t0 + Duration::from_millis(350)), None);
        let v = w.check(t0 + Duration::from_millis(450)).unwrap();
        assert!(v.starts_with("the display was hidden for 550 ms"), "{v}");
        // Visible again in time: the hidden time stays what the page counted.
        let mut w = DisplayWatch::new(1, LIMITS, t0);
        w.report(t0, report(true, 16.0, 0.0));
        let back = t0 + Duration::from_millis(200);
        assert_eq!(w.report(back, report(false, 16.0, 200.0)), None);
        assert_eq!(w.check(back + Duration::from_millis(900)), None);
    }

    #[test]
    fn a_stalled_or_silent_display_is_invalid() {
        let t0 = Instant::now();
        let mut w = DisplayWatch::new(1, LIMITS, t0);
        let v = w.report(t0, report(false, 1500.0, 0.0)).unwrap();
        assert!(v.contains("no frame for 1500 ms"), "{v}");
        // Silence counts from the start plus the grace, then from each report.
        let w = DisplayWatch::new(1, LIMITS, t0);
        assert_eq!(w.check(t0 + START_GRACE + Duration::from_millis(900)), None);
        let v = w
            .check(t0 + START_GRACE + Duration::from_millis(1100))
            .unwrap();
        assert!(v.contains("no display report for 1100 ms"), "{v}");
    }
}
