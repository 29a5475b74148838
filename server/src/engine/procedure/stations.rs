//! Stations: pairing a browser by the code it shows, assigning a subject, and what a station
//! shows now — the subject's view (blinded) and the experimenter's view of it.

use std::collections::{HashMap, VecDeque};
use std::net::IpAddr;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use bdft_protocol::params::Seat;
use bdft_protocol::records::{ConsentDecision, DoneReason, StationRole, TestPhase, TrialStatus};
use bdft_protocol::server_to_browser::{
    MonitorStation, MonitorTest, MonitorView, Phase, StationInfo, StationView, TestView,
};
use serde::Serialize;
use sqlx::AnyPool;

use bdft_protocol::study::{ConsentForm, StudyParams, StudyTexts};

use super::queue;
use super::station_sockets::StationSockets;
use crate::engine::machine::sites::Sites;
use crate::error::{AppError, Result};
use crate::store::stations::Station;
use crate::store::studies::Study;
use crate::store::subjects::Subject;
use crate::store::trials::{Trial, latest_attempts};
use crate::store::{self, Change};

/// Letters and digits that cannot be mistaken for one another when read off a screen.
const CODE_ALPHABET: &[u8] = b"ABCDEFGHJKLMNPQRSTUVWXYZ23456789";
/// How long a shown pairing code stays valid.
const CODE_LIFETIME: Duration = Duration::from_secs(3600);
/// Codes shown at once, at most: far more stations than a lab pairs in an hour, and a
/// bound on what anonymous callers of the register endpoint can make the server keep.
pub const MAX_PENDING: usize = 256;
/// How long a station's wait for its pairing is held open before it is answered "not
/// yet" (the page asks again): below the usual 30 to 60 s proxy timeouts.
pub const PAIRING_WAIT: Duration = Duration::from_secs(25);

/// What one client address may ask of the anonymous register endpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PairingLimits {
    /// Registrations per minute from one address; more are refused (429).
    pub per_minute: usize,
    /// Codes one address has shown at once; its next registration withdraws its oldest, so
    /// one address never holds more than this of the [`MAX_PENDING`].
    pub codes_per_address: usize,
}

impl Default for PairingLimits {
    fn default() -> Self {
        Self {
            per_minute: 20,
            codes_per_address: 16,
        }
    }
}

/// The window of [`PairingLimits::per_minute`].
const REGISTRATION_WINDOW: Duration = Duration::from_secs(60);
/// Addresses whose registrations of the last minute are remembered at most: past it (after
/// a sweep) a new address is refused until the window frees room, rather than forgetting an
/// address that is over its limit.
const MAX_ADDRESSES: usize = 4096;

/// A station that shows a code and waits for the experimenter.
#[derive(Debug)]
struct Pending {
    token: String,
    shown_at: Instant,
    /// The address that registered it.
    from: IpAddr,
}

/// Stations that showed a pairing code and wait for the experimenter: code → token.
/// Kept in memory: a code is good for an hour or until the server restarts. Bounded by
/// [`MAX_PENDING`], and per client address by [`PairingLimits`]; waiters for a pairing are
/// bounded by the same number.
#[derive(Debug, Default)]
pub struct Pairing {
    limits: PairingLimits,
    codes: Mutex<Codes>,
    /// Woken at every pairing: the stations waiting look whether it was theirs.
    paired: tokio::sync::Notify,
    waiting: std::sync::atomic::AtomicUsize,
}

#[derive(Debug, Default)]
struct Codes {
    pending: HashMap<String, Pending>,
    /// Each address's registrations of the last [`REGISTRATION_WINDOW`], oldest first.
    registered: HashMap<IpAddr, VecDeque<Instant>>,
    last_sweep: Option<Instant>,
}

/// Where a station that registered stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairingState {
    /// Its code is shown and still valid.
    Pending,
    /// The experimenter paired it: its token now works.
    Paired,
    /// The token is neither pending nor paired (expired, never registered, server
    /// restarted): register again.
    Unknown,
}

impl Pairing {
    pub fn new(limits: PairingLimits) -> Self {
        Self {
            limits,
            ..Self::default()
        }
    }

    fn codes(&self) -> std::sync::MutexGuard<'_, Codes> {
        self.codes.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// A new station's (bearer token, pairing code), registered from `from` at `now`;
    /// refused (429, with when to ask again) past the address's registrations per minute,
    /// and (503) while [`MAX_PENDING`] codes are shown. An address showing its limit of
    /// codes has its oldest withdrawn (that page, waiting, is told to register again).
    pub fn register(&self, from: IpAddr, now: Instant) -> Result<(String, String)> {
        let limits = self.limits;
        let mut codes = self.codes();
        let codes = &mut *codes;
        codes
            .pending
            .retain(|_, p| now.saturating_duration_since(p.shown_at) < CODE_LIFETIME);
        let live = |t: &Instant| now.saturating_duration_since(*t) < REGISTRATION_WINDOW;
        if codes
            .last_sweep
            .is_none_or(|t| now.saturating_duration_since(t) >= REGISTRATION_WINDOW)
            || codes.registered.len() >= MAX_ADDRESSES
        {
            codes.registered.retain(|_, times| {
                times.retain(live);
                !times.is_empty()
            });
            codes.last_sweep = Some(now);
        }
        if !codes.registered.contains_key(&from) && codes.registered.len() >= MAX_ADDRESSES {
            return Err(AppError::TooManyRequests {
                message: format!(
                    "stations were registered from {MAX_ADDRESSES} addresses within a minute, \
                     the most the server remembers: try again in a minute"
                ),
                retry_after: REGISTRATION_WINDOW,
            });
        }
        let times = codes.registered.entry(from).or_default();
        times.retain(live);
        if times.len() >= limits.per_minute {
            let oldest = times.front().copied().unwrap_or(now);
            let retry_after = (oldest + REGISTRATION_WINDOW).saturating_duration_since(now);
            return Err(AppError::TooManyRequests {
                message: format!(
                    "{} stations were registered from this address within a minute, the most it may \
                     (--station-registrations-per-minute): try again in {} s",
                    limits.per_minute,
                    crate::error::whole_seconds(retry_after),
                ),
                retry_after,
            });
        }
        let mine: Vec<(&String, Instant)> = codes
            .pending
            .iter()
            .filter(|(_, p)| p.from == from)
            .map(|(code, p)| (code, p.shown_at))
            .collect();
        if mine.len() >= limits.codes_per_address {
            let oldest = mine
                .iter()
                .min_by_key(|(_, at)| *at)
                .map(|(code, _)| (*code).clone());
            if let Some(code) = oldest {
                codes.pending.remove(&code);
            }
        }
        if codes.pending.len() >= MAX_PENDING {
            return Err(AppError::Unavailable(format!(
                "{MAX_PENDING} stations already show a pairing code: pair them, or wait until \
                 their codes expire (an hour after they were shown)"
            )));
        }
        times.push_back(now);
        let token = store::tokens::random_token();
        let code = loop {
            let code = new_code();
            if !codes.pending.contains_key(&code) {
                break code;
            }
        };
        codes.pending.insert(
            code.clone(),
            Pending {
                token: token.clone(),
                shown_at: now,
                from,
            },
        );
        Ok((token, code))
    }

    /// The token of the station showing `code`, which is used up; the stations waiting
    /// are woken to look.
    /// The token of the station showing `code`. The code stays pending until the pairing
    /// is committed ([`Self::forget`]): a station waiting meanwhile sees it pending or
    /// paired, never unknown, and a failed pairing loses no code.
    fn token_of(&self, code: &str) -> Option<String> {
        let mut codes = self.codes();
        codes
            .pending
            .retain(|_, p| p.shown_at.elapsed() < CODE_LIFETIME);
        codes.pending.get(code).map(|p| p.token.clone())
    }

    fn forget(&self, code: &str) {
        self.codes().pending.remove(code);
    }

    fn is_pending(&self, token: &str) -> bool {
        self.codes()
            .pending
            .values()
            .any(|p| p.token == token && p.shown_at.elapsed() < CODE_LIFETIME)
    }

    /// Waits until the station of `token` is paired, for at most `limit`: a page that shows
    /// its code asks this instead of polling (and logging a 401 every second).
    pub async fn wait(&self, pool: &AnyPool, token: &str, limit: Duration) -> Result<PairingState> {
        let _waiting = Waiter::enter(&self.waiting)?;
        let deadline = tokio::time::Instant::now() + limit;
        loop {
            // Registered before looking, so that a pairing in between is not missed.
            let woken = self.paired.notified();
            tokio::pin!(woken);
            woken.as_mut().enable();
            if !self.is_pending(token) {
                let paired = store::stations::by_token(pool, token).await?.is_some();
                return Ok(if paired {
                    PairingState::Paired
                } else {
                    PairingState::Unknown
                });
            }
            if tokio::time::timeout_at(deadline, woken).await.is_err() {
                return Ok(PairingState::Pending);
            }
        }
    }
}

/// One of at most [`MAX_PENDING`] waits for a pairing; leaving (also by a dropped
/// request) frees its place.
struct Waiter<'a>(&'a std::sync::atomic::AtomicUsize);

impl<'a> Waiter<'a> {
    fn enter(count: &'a std::sync::atomic::AtomicUsize) -> Result<Self> {
        use std::sync::atomic::Ordering;
        if count.fetch_add(1, Ordering::SeqCst) >= MAX_PENDING {
            count.fetch_sub(1, Ordering::SeqCst);
            return Err(AppError::Unavailable(
                "too many stations are waiting to be paired; try again in a few seconds".into(),
            ));
        }
        Ok(Self(count))
    }
}

impl Drop for Waiter<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
    }
}

/// Six symbols of [`CODE_ALPHABET`] from the OS random source.
fn new_code() -> String {
    let mut bytes = [0u8; 6];
    getrandom::fill(&mut bytes).expect("the OS random source works");
    // 32 symbols divide 256, so every symbol is equally likely.
    bytes
        .iter()
        .map(|b| CODE_ALPHABET[usize::from(*b) % CODE_ALPHABET.len()] as char)
        .collect()
}

/// What `station.pair` records: the station's name, role and site.
#[derive(Debug, Serialize)]
struct Paired<'a> {
    name: &'a str,
    role: StationRole,
    site: &'a str,
}

/// A station to pair: its name, the seats it serves, and the site it is at (one the
/// server serves).
#[derive(Debug, Clone, Copy)]
pub struct NewStation<'a> {
    pub name: &'a str,
    pub role: StationRole,
    pub site: &'a str,
}

/// Pairs the station showing `pairing_code` with a study; returns its id.
pub async fn pair(
    pool: &AnyPool,
    pairing: &Pairing,
    actor: &str,
    study_id: i64,
    pairing_code: &str,
    NewStation { name, role, site }: NewStation<'_>,
) -> Result<i64> {
    store::studies::get(pool, study_id).await?;
    crate::engine::check_name(name)?;
    let code = pairing_code.trim().to_uppercase();
    let token = pairing.token_of(&code).ok_or_else(|| {
        AppError::BadRequest(format!(
            "pairing code {code:?} is not shown by any station (codes expire after an hour)"
        ))
    })?;
    let mut change = Change::begin(pool, actor).await?;
    let id =
        store::stations::insert(change.db(), study_id, name, role, site, &token, &code).await?;
    change
        .commit(
            "station.pair",
            Some(format!("station:{id}")),
            Paired { name, role, site },
        )
        .await?;
    pairing.forget(&code);
    pairing.paired.notify_waiters();
    Ok(id)
}

/// What `station.assign` records: the subject now at the station (null: none).
#[derive(Debug, Serialize)]
struct Assigned {
    subject_id: Option<i64>,
}

/// Assigns a subject of the station's study to it (or none). A subject's stations are at
/// one site: its tests run on that site's machine.
pub async fn assign(
    pool: &AnyPool,
    sites: &Sites,
    actor: &str,
    station_id: i64,
    subject_id: Option<i64>,
) -> Result<()> {
    let mut change = Change::begin(pool, actor).await?;
    let station = store::stations::get(change.db(), station_id).await?;
    if let Some(subject_id) = subject_id {
        let subject = store::subjects::get(change.db(), subject_id).await?;
        if subject.study_id != station.study_id {
            return Err(AppError::BadRequest(
                "the subject belongs to another study".into(),
            ));
        }
        if subject.erased_at.is_some() {
            return Err(store::subjects::refuse_erased(&subject));
        }
        // One input source per test: a subject may be at a desk station and a machine
        // station, never at two stations that serve the same seat (both would feed it).
        let others = store::stations::of_subject(change.db(), subject_id).await?;
        if let Some(other) = others
            .iter()
            .find(|o| o.id != station_id && shares_a_seat(o.role, station.role))
        {
            return Err(AppError::Conflict(format!(
                "{} is already assigned to station {:?}, which serves the same seat; unassign it there first",
                subject.code, other.name
            )));
        }
        let here = sites.name_of(station.site.as_deref());
        if let Some(other) = others
            .iter()
            .find(|o| sites.name_of(o.site.as_deref()) != here)
        {
            return Err(AppError::Conflict(format!(
                "{} is already assigned to station {:?} at site {:?}, and this station is at site {here:?}: a subject's tests run on one site's machine; unassign it there first",
                subject.code,
                other.name,
                sites.name_of(other.site.as_deref())
            )));
        }
    }
    store::stations::assign(change.db(), station_id, subject_id).await?;
    change
        .commit(
            "station.assign",
            Some(format!("station:{station_id}")),
            Assigned { subject_id },
        )
        .await
}

/// The stored site of `subject_id`'s stations (a subject's stations are at one site; none
/// for a subject at no station, or at stations paired before sites existed: the server's
/// first site).
pub async fn subject_site(pool: &AnyPool, subject_id: i64) -> Result<Option<String>> {
    let stations = store::stations::of_subject(pool, subject_id).await?;
    Ok(stations.into_iter().next().and_then(|s| s.site))
}

/// The site whose machine trial `trial_id` drives: the one it ran at (recorded when it
/// started), or else its subject's stations' site, as `trials::start` runs it. What
/// starting or aborting it is checked against for an account limited to sites.
pub async fn site_driven_by(pool: &AnyPool, sites: &Sites, trial_id: i64) -> Result<String> {
    let trial = store::trials::get(pool, trial_id).await?;
    if let Some(site) = trial.site {
        return Ok(site);
    }
    let stored = subject_site(pool, trial.subject_id).await?;
    Ok(sites.name_of(stored.as_deref()).to_string())
}

/// Whether two stations' roles have a seat in common.
fn shares_a_seat(a: StationRole, b: StationRole) -> bool {
    [Seat::On, Seat::Off]
        .into_iter()
        .any(|seat| a.serves(seat) && b.serves(seat))
}

/// The consent form and the texts of a study with their placeholders filled in. A study
/// stored before texts had placeholders may hold a brace that is not one: then its texts are
/// shown as written.
pub fn rendered_texts(params: &StudyParams) -> (ConsentForm, StudyTexts) {
    params
        .rendered_texts()
        .unwrap_or_else(|_| (params.consent.clone(), params.texts.clone()))
}

/// The consent form a study's subjects are shown: the text its lock rendered from the
/// protocol, or (before the lock, or for a study locked before the text was kept) the form
/// rendered now.
pub fn consent_form(study: &Study) -> ConsentForm {
    match &study.consent_text {
        Some(text) => ConsentForm {
            version: study.params.consent.version.clone(),
            text: text.clone(),
        },
        None => rendered_texts(&study.params).0,
    }
}

/// What `station` shows now, with each test given by `test` (blinded for the subject,
/// with the compensator for the experimenter), and the study's texts filled in.
async fn phase<T>(
    pool: &AnyPool,
    station: &Station,
    test: impl Fn(TestView, &Trial) -> T,
) -> Result<(Phase<T>, Option<StudyTexts>)> {
    let Some(subject_id) = station.subject_id else {
        return Ok((Phase::Waiting, None));
    };
    let subject = store::subjects::get(pool, subject_id).await?;
    let study = store::studies::get(pool, subject.study_id).await?;
    let (_, texts) = rendered_texts(&study.params);
    let phase = subject_phase(pool, station, &subject, &study, consent_form(&study), test).await?;
    Ok((phase, Some(texts)))
}

/// Where the station's subject is in the protocol.
async fn subject_phase<T>(
    pool: &AnyPool,
    station: &Station,
    subject: &Subject,
    study: &Study,
    consent: ConsentForm,
    test: impl Fn(TestView, &Trial) -> T,
) -> Result<Phase<T>> {
    let subject_id = subject.id;
    let code = subject.code.clone();
    if subject.withdrawn_at.is_some() {
        return Ok(Phase::Done {
            subject: code,
            reason: DoneReason::Withdrawn,
        });
    }
    match subject.consent_decision {
        None => {
            return Ok(Phase::Consent {
                subject: code,
                consent,
            });
        }
        Some(ConsentDecision::Declined) => {
            return Ok(Phase::Done {
                subject: code,
                reason: DoneReason::Declined,
            });
        }
        Some(ConsentDecision::Agreed) => {}
    }
    if let Some(t) = store::trials::pending_survey(pool, subject_id).await? {
        // The survey is answered where the test was run; another station sends the
        // subject there.
        if !station.role.serves(t.seat) {
            return Ok(Phase::Move {
                subject: code,
                to: t.seat,
            });
        }
        return Ok(Phase::Survey {
            subject: code,
            trial_id: t.id,
            label: t.blinded_label,
            survey: study.params.survey.clone(),
        });
    }
    let trials = store::trials::of_subject(pool, subject_id).await?;
    let total = latest_attempts(&trials)
        .filter(|t| t.phase.scored())
        .count();
    let Some(t) = store::trials::next(pool, subject_id).await? else {
        // Never "done" while a test is missing: one that failed too often waits for the
        // experimenter.
        return Ok(if queue::anything_missing(&trials) {
            Phase::Held {
                subject: code,
                failed: queue::held_test(&trials),
            }
        } else {
            Phase::Done {
                subject: code,
                reason: DoneReason::Finished,
            }
        });
    };
    if !station.role.serves(t.seat) {
        return Ok(Phase::Move {
            subject: code,
            to: t.seat,
        });
    }
    let view = TestView {
        trial_id: t.id,
        label: t.blinded_label.clone(),
        phase: t.phase,
        instructions: (t.phase == TestPhase::Identification).then(|| {
            study
                .params
                .identification
                .as_ref()
                .map(|id| id.instructions_for())
                .unwrap_or_default()
        }),
        number: t.slot,
        of: total as i64,
        duration_s: t.duration_s,
        seat: t.seat,
        shake_gain: if t.seat == Seat::On {
            study.params.display_shake_gain
        } else {
            0.0
        },
        target_range_mm: study.params.target_range_mm,
        k_bf: t.k_bf,
        started_at: t.started_at,
    };
    let test = test(view, &t);
    Ok(if t.status == TrialStatus::Running {
        Phase::Running {
            subject: code,
            test,
        }
    } else {
        Phase::Ready {
            subject: code,
            test,
        }
    })
}

/// What the station shows its subject now (never a compensator's name), with what
/// happened to the last test when it was stopped.
pub async fn station_view(pool: &AnyPool, station: &Station) -> Result<StationView> {
    let (phase, texts) = phase(pool, station, |view, _| view).await?;
    let stopped = match (&phase, station.subject_id) {
        (Phase::Ready { .. } | Phase::Move { .. } | Phase::Held { .. }, Some(subject_id)) => {
            queue::stop_notice(&store::trials::of_subject(pool, subject_id).await?)
        }
        _ => None,
    };
    Ok(StationView {
        station: StationInfo {
            name: station.name.clone(),
            role: station.role,
        },
        phase,
        stopped,
        texts,
    })
}

/// What a station shows, for the experimenter's live monitor (with the compensator of the
/// test at hand).
pub async fn monitor_view(
    pool: &AnyPool,
    sockets: &StationSockets,
    station_id: i64,
) -> Result<MonitorView> {
    let station = store::stations::get(pool, station_id).await?;
    Ok(MonitorView {
        phase: phase(pool, &station, |test, t| MonitorTest {
            test,
            compensator: t.compensator,
        })
        .await?
        .0,
        station: MonitorStation {
            id: station.id,
            name: station.name,
            role: station.role,
            subject_id: station.subject_id,
            socket: sockets.view(station.id),
        },
    })
}

/// The trial a station may feed with operator input now: its subject's running test at a
/// seat the station serves.
pub async fn running_trial(pool: &AnyPool, station_id: i64) -> Result<Option<i64>> {
    let station = store::stations::get(pool, station_id).await?;
    let Some(subject_id) = station.subject_id else {
        return Ok(None);
    };
    let next = store::trials::next(pool, subject_id).await?;
    Ok(next
        .filter(|t| t.status == TrialStatus::Running && station.role.serves(t.seat))
        .map(|t| t.id))
}

/// A test of the station's subject (a station never touches another subject's data).
pub async fn own_trial(pool: &AnyPool, station: &Station, trial_id: i64) -> Result<Trial> {
    let subject_id = subject_of(station)?;
    let trial = store::trials::get(pool, trial_id).await?;
    if trial.subject_id != subject_id {
        return Err(AppError::Forbidden(
            "this test belongs to another subject".into(),
        ));
    }
    Ok(trial)
}

/// The subject assigned to the station.
pub fn subject_of(station: &Station) -> Result<i64> {
    station
        .subject_id
        .ok_or_else(|| AppError::Conflict("no subject is assigned to this station".into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(last: u8) -> IpAddr {
        IpAddr::from([10, 0, 0, last])
    }

    #[test]
    fn one_address_registers_at_most_its_limit_a_minute_and_shows_at_most_its_codes() {
        let pairing = Pairing::new(PairingLimits {
            per_minute: 5,
            codes_per_address: 3,
        });
        let t0 = Instant::now();
        let codes: Vec<String> = (0..5)
            .map(|i| {
                pairing
                    .register(ip(1), t0 + Duration::from_secs(i))
                    .unwrap()
                    .1
            })
            .collect();
        // Refused until the first registration leaves the minute.
        let later = t0 + Duration::from_secs(20);
        match pairing.register(ip(1), later) {
            Err(AppError::TooManyRequests {
                message,
                retry_after,
            }) => {
                assert_eq!(retry_after, Duration::from_secs(40));
                assert!(message.contains("try again in 40 s"), "{message}");
            }
            other => panic!("{other:?}"),
        }
        // Its three newest codes are shown, the two oldest withdrawn.
        let shown = |code: &str| pairing.token_of(code).is_some();
        assert!(!shown(&codes[0]) && !shown(&codes[1]));
        assert!(codes[2..].iter().all(|c| shown(c)));
        // Another address is not limited by the first's registrations.
        assert!(pairing.register(ip(2), later).is_ok());
        // A minute after the first registration, the first address may again.
        assert!(
            pairing
                .register(ip(1), t0 + Duration::from_secs(60))
                .is_ok()
        );
    }
}
