//! Experimenter accounts: credentials rules, roles and their management by an admin (never
//! deleted, only disabled; the last active admin stays), the sites an account is limited to
//! (`may_drive`: the machines it may start, abort, reset and run the bench on), rate-limited login
//! (`login_limiter`, with argon2id in bounded memory from `passwords`), the one-time set-up
//! link and sessions. No HTTP here: `http::session` carries cookies.
//!
//! Files: `mod.rs` (credentials, roles, account management with the last-admin rule, the sites an
//! account is limited to — checked against the server's sites —, and `may_drive`, the refusal of a
//! limited account's start, abort, reset or bench run at another site's machine, read at each
//! action, login, the set-up link — one at a time, valid for an hour —, sessions), `login_limiter`
//! (attempts reserved before the check, per username and address and per address; bounded, swept; a
//! refusal says when the oldest attempt leaves the window, the 429's Retry-After), `passwords`
//! (argon2id, two at a time in reused buffers: bounded memory), `estop_sessions` (the sessions the
//! store confirmed within the hour, bounded: the E-stop's route alone is authenticated from them,
//! so a busy store cannot delay it; a logout forgets one at once).

pub mod estop_sessions;
pub mod login_limiter;
pub mod passwords;

use std::net::IpAddr;
use std::time::{Duration, Instant};

use serde::Serialize;
use sqlx::AnyPool;

use self::login_limiter::LoginLimiter;
use crate::error::{AppError, Result};
use crate::store::accounts::{Account, Role};
use crate::store::audit::NoDetail;
use crate::store::tokens::random_token;
use crate::store::{self, Change};

const MIN_PASSWORD: usize = 10;
const MAX_PASSWORD_BYTES: usize = 200;
/// Longest username (characters, which are ASCII: bytes too): the rule for new accounts, and
/// what a login may send.
const MAX_USERNAME: usize = 40;
/// How long a session lasts.
pub const SESSION_HOURS: i64 = 12;
/// How long a set-up link is valid.
pub const SETUP_LINK_LIFETIME: Duration = Duration::from_secs(3600);

/// A real hash of a random password, so that unknown usernames cost the same verification.
async fn dummy_hash() -> Result<String> {
    static DUMMY: tokio::sync::OnceCell<String> = tokio::sync::OnceCell::const_new();
    Ok(DUMMY
        .get_or_try_init(|| async { passwords::hash(&random_token()).await })
        .await?
        .clone())
}

fn check_new_credentials(username: &str, password: &str) -> Result<()> {
    // The rule of every name first (its length and what no name holds), then the username's
    // own alphabet: it must never contain ':' or ' ', which mark the non-person actors of the
    // audit log.
    crate::engine::name_rule("username", username, 3, MAX_USERNAME)
        .map_err(AppError::BadRequest)?;
    let ok_name = username
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || "._-".contains(c));
    if !ok_name {
        return Err(AppError::BadRequest(format!(
            "username: 3 to {MAX_USERNAME} of the letters a–z and A–Z, digits, '.', '_' or '-'"
        )));
    }
    if password.chars().count() < MIN_PASSWORD || password.len() > MAX_PASSWORD_BYTES {
        return Err(AppError::BadRequest(format!(
            "password: at least {MIN_PASSWORD} characters (at most {MAX_PASSWORD_BYTES} bytes)"
        )));
    }
    Ok(())
}

/// What `experimenter.create` records (the sites only of an account limited to some).
#[derive(Debug, Serialize)]
struct Created<'a> {
    username: &'a str,
    role: Role,
    #[serde(skip_serializing_if = "Option::is_none")]
    sites: Option<&'a [String]>,
}

/// The sites an admin limits an account to, and the sites this server serves (`serve
/// --site`), which they must be among.
#[derive(Debug, Clone, Copy)]
pub struct SiteLimit<'a> {
    pub sites: &'a [String],
    pub served: &'a [&'a str],
}

impl SiteLimit<'_> {
    /// The sites to store: each one served, at least one, each once, sorted by name; or
    /// a 422 naming the server's sites.
    fn checked(&self) -> Result<Vec<String>> {
        let served = self.served.join(", ");
        if self.sites.is_empty() {
            return Err(AppError::BadRequest(format!(
                "sites: at least one of this server's sites ({served}), or null for every site"
            )));
        }
        if let Some(other) = self
            .sites
            .iter()
            .find(|s| !self.served.contains(&s.as_str()))
        {
            return Err(AppError::BadRequest(format!(
                "sites: this server has no site {other:?}; its sites are {served} (null: every site)"
            )));
        }
        let mut sites = self.sites.to_vec();
        sites.sort();
        sites.dedup();
        Ok(sites)
    }
}

/// Creates an account with `role` on behalf of `actor` (an admin, or `system:startup` for
/// `--admin-password`), not limited to sites; returns it.
pub async fn create_experimenter(
    pool: &AnyPool,
    actor: &str,
    username: &str,
    password: &str,
    role: Role,
) -> Result<Account> {
    create_account(pool, actor, username, password, role, None).await
}

/// Creates an account with `role` on behalf of the admin `actor`, limited to the sites of
/// `limit` when given (otherwise it drives every site's machine); returns it.
pub async fn create_account(
    pool: &AnyPool,
    actor: &str,
    username: &str,
    password: &str,
    role: Role,
    limit: Option<SiteLimit<'_>>,
) -> Result<Account> {
    check_new_credentials(username, password)?;
    let sites = limit.map(|l| l.checked()).transpose()?;
    let hash = passwords::hash(password).await?;
    let mut change = Change::begin(pool, actor).await?;
    let id = store::accounts::insert_experimenter(change.db(), username, &hash, role).await?;
    store::accounts::set_sites(change.db(), id, sites.as_deref()).await?;
    let account = store::accounts::account(change.db(), id).await?;
    change
        .commit(
            "experimenter.create",
            Some(format!("experimenter:{id}")),
            Created {
                username,
                role,
                sites: sites.as_deref(),
            },
        )
        .await?;
    Ok(account)
}

/// What `experimenter.sites` records: the sites before and after (null: every site).
#[derive(Debug, Serialize)]
struct SitesChanged<'a> {
    username: &'a str,
    from: Option<&'a [String]>,
    to: Option<&'a [String]>,
}

/// Limits an account to the sites of `limit`, or (none) lets it drive every site's machine
/// again (`admin` is the admin making the change). It applies to the account's sessions at
/// once: every check reads it when the action comes.
pub async fn set_sites(
    pool: &AnyPool,
    admin: &str,
    id: i64,
    limit: Option<SiteLimit<'_>>,
) -> Result<Account> {
    let sites = limit.map(|l| l.checked()).transpose()?;
    let mut change = Change::begin(pool, admin).await?;
    let before = store::accounts::account(change.db(), id).await?;
    store::accounts::set_sites(change.db(), id, sites.as_deref()).await?;
    let after = store::accounts::account(change.db(), id).await?;
    change
        .commit(
            "experimenter.sites",
            Some(format!("experimenter:{id}")),
            SitesChanged {
                username: &before.username,
                from: before.sites.as_deref(),
                to: sites.as_deref(),
            },
        )
        .await?;
    Ok(after)
}

/// What drives a site's machine, as a refusal words it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Drive {
    /// Starting a test on its subject's site's machine.
    Start,
    /// Aborting a test where it runs.
    Abort,
    /// Resetting one site's E-stop latch.
    Reset,
    /// Resetting the latch of every site at once (and each site's own).
    ResetEverySite,
    /// A bench run on a site's real machine.
    Bench,
}

/// `site "a"` or `sites "a" and "b"`.
fn sites_words(sites: &[&str]) -> String {
    let quoted: Vec<String> = sites.iter().map(|s| format!("{s:?}")).collect();
    match quoted.as_slice() {
        [one] => format!("site {one}"),
        [rest @ .., last] => format!("sites {} and {last}", rest.join(", ")),
        [] => "no site".into(),
    }
}

/// Refuses (403) `action` when account `id` is limited to sites and the action drives the
/// machine of one not among them; `sites` are the sites it drives (every site's for
/// [`Drive::ResetEverySite`]). An account not limited drives every site's machine. Read at
/// each action, so an admin's change applies to sessions at once. The E-stop itself is
/// never checked: any account stops any site's machine.
pub async fn may_drive(pool: &AnyPool, id: i64, action: Drive, sites: &[&str]) -> Result<()> {
    let Some(own) = store::accounts::sites(pool, id).await? else {
        return Ok(());
    };
    let outside: Vec<&str> = sites
        .iter()
        .copied()
        .filter(|s| !own.iter().any(|o| o == s))
        .collect();
    if outside.is_empty() {
        return Ok(());
    }
    let other = sites_words(&outside);
    let what = match action {
        Drive::Start => format!("starting a test at {other}"),
        Drive::Abort => format!("aborting a test at {other}"),
        Drive::Reset => format!("resetting the E-stop of {other}"),
        Drive::ResetEverySite => format!(
            "resetting the E-stop of every site (which includes {other}; reset your site's alone: POST /api/estop/reset?site=NAME)"
        ),
        Drive::Bench => format!("running the bench on the machine of {other}"),
    };
    let own: Vec<&str> = own.iter().map(String::as_str).collect();
    Err(AppError::Forbidden(format!(
        "{what} is refused: your account is limited to {} (an admin sets an account's sites; any account may still press any E-stop)",
        sites_words(&own)
    )))
}

/// Refuses a change that would leave no active admin (nobody could manage accounts then).
async fn keep_an_admin(db: &mut sqlx::AnyConnection, account: &Account) -> Result<()> {
    let active_admin = account.role == Role::Admin && account.disabled_at.is_none();
    if active_admin && store::accounts::other_active_admins(&mut *db, account.id).await? == 0 {
        return Err(AppError::Conflict(format!(
            "{} is the last active admin: make another account admin first",
            account.username
        )));
    }
    Ok(())
}

/// What `experimenter.role` records.
#[derive(Debug, Serialize)]
struct RoleChanged<'a> {
    username: &'a str,
    from: Role,
    to: Role,
}

/// Gives an account another role (`admin` is the admin making the change).
pub async fn set_role(pool: &AnyPool, admin: &str, id: i64, role: Role) -> Result<Account> {
    let mut change = Change::begin(pool, admin).await?;
    let before = store::accounts::account(change.db(), id).await?;
    if role != Role::Admin {
        keep_an_admin(change.db(), &before).await?;
    }
    store::accounts::set_role(change.db(), id, role).await?;
    let after = store::accounts::account(change.db(), id).await?;
    change
        .commit(
            "experimenter.role",
            Some(format!("experimenter:{id}")),
            RoleChanged {
                username: &before.username,
                from: before.role,
                to: role,
            },
        )
        .await?;
    Ok(after)
}

/// What an action on an account names it by: `experimenter.enable`, `setup.first_account`,
/// and `experimenter.disable` with the sessions that ended.
#[derive(Debug, Serialize)]
struct Named<'a> {
    username: &'a str,
    #[serde(skip_serializing_if = "Option::is_none")]
    sessions_ended: Option<u64>,
}

/// Disables an account (it cannot log in; its sessions end at once) or enables it again.
pub async fn set_disabled(pool: &AnyPool, admin: &str, id: i64, disabled: bool) -> Result<Account> {
    let mut change = Change::begin(pool, admin).await?;
    let before = store::accounts::account(change.db(), id).await?;
    let (action, sessions_ended) = if disabled {
        keep_an_admin(change.db(), &before).await?;
        let ended = store::accounts::disable(change.db(), id).await?;
        ("experimenter.disable", Some(ended))
    } else {
        store::accounts::enable(change.db(), id).await?;
        ("experimenter.enable", None)
    };
    let detail = Named {
        username: &before.username,
        sessions_ended,
    };
    let after = store::accounts::account(change.db(), id).await?;
    change
        .commit(action, Some(format!("experimenter:{id}")), detail)
        .await?;
    Ok(after)
}

/// What `setup.link` records: whether an unused link was replaced.
#[derive(Debug, Serialize)]
struct SetupLink {
    replaced_unused: u64,
}

/// A one-time set-up token (printed at a start with no account); only its hash is stored.
/// It replaces any earlier unused one, so at most one set-up link is ever valid.
pub async fn new_setup_token(pool: &AnyPool) -> Result<String> {
    let token = random_token();
    let mut change = Change::begin(pool, "system:startup").await?;
    let replaced = store::accounts::replace_setup_token(change.db(), &token).await?;
    change
        .commit(
            "setup.link",
            None,
            SetupLink {
                replaced_unused: replaced,
            },
        )
        .await?;
    Ok(token)
}

fn setup_done() -> AppError {
    AppError::Conflict("set-up is done: an experimenter account exists; log in instead".into())
}

/// Why a set-up token cannot be used, if it cannot.
async fn check_setup_token<'c>(db: impl sqlx::AnyExecutor<'c>, token: &str) -> Result<()> {
    let lifetime_ms = SETUP_LINK_LIFETIME.as_millis() as i64;
    match store::accounts::setup_token(db, token).await? {
        None => Err(AppError::Forbidden(
            "the set-up link is not valid: mistyped, or replaced by a newer one (only the link printed at the server's last start works)".into(),
        )),
        Some(t) if t.used_at.is_some() => Err(AppError::Conflict(
            "the set-up link was used already: log in with the account it created".into(),
        )),
        Some(t) if store::db::now_ms() - t.created_at >= lifetime_ms => Err(AppError::Forbidden(
            format!(
                "the set-up link expired (it is valid for {} minutes): restart the server for a new one",
                lifetime_ms / 60_000
            ),
        )),
        Some(_) => Ok(()),
    }
}

/// Creates the first experimenter, an admin, with the one-time set-up token: the token is used and the
/// account made in one immediate transaction, so of two concurrent uses exactly one makes
/// an account.
pub async fn first_account(
    pool: &AnyPool,
    token: &str,
    username: &str,
    password: &str,
) -> Result<i64> {
    if store::accounts::experimenter_count(pool).await? > 0 {
        return Err(setup_done());
    }
    check_new_credentials(username, password)?;
    // Checked before hashing too, so that wrong links cost no argon2 work.
    check_setup_token(pool, token).await?;
    let hash = passwords::hash(password).await?;
    let mut change = Change::begin(pool, username).await?;
    if store::accounts::experimenter_count(change.db()).await? > 0 {
        return Err(setup_done());
    }
    check_setup_token(change.db(), token).await?;
    store::accounts::use_setup_token(change.db(), token).await?;
    let id =
        store::accounts::insert_experimenter(change.db(), username, &hash, Role::Admin).await?;
    change
        .commit(
            "setup.first_account",
            Some(format!("experimenter:{id}")),
            Named {
                username,
                sessions_ended: None,
            },
        )
        .await?;
    Ok(id)
}

/// A new session of an account.
#[derive(Debug)]
pub struct NewSession {
    /// The cookie's token.
    pub token: String,
    /// The token state-changing requests echo in a header.
    pub csrf: String,
    pub role: Role,
}

/// How a session began, as its `login` audit row records it.
#[derive(Debug, Serialize)]
#[serde(tag = "after", rename_all = "lowercase")]
pub enum Login {
    /// The first account's session, opened by the set-up itself: `{"after":"setup"}`.
    Setup,
    /// A password checked, from the client's address: `{"from":"127.0.0.1"}`.
    #[serde(untagged)]
    Password { from: String },
}

/// A new session of an account, audited as `login`.
pub async fn new_session(
    pool: &AnyPool,
    experimenter_id: i64,
    username: &str,
    role: Role,
    how: Login,
) -> Result<NewSession> {
    let (token, csrf) = (random_token(), random_token());
    let mut change = Change::begin(pool, username).await?;
    store::accounts::insert_session(
        change.db(),
        &token,
        experimenter_id,
        &csrf,
        SESSION_HOURS * 3_600_000,
    )
    .await?;
    change.commit("login", None, how).await?;
    Ok(NewSession { token, csrf, role })
}

pub async fn end_session(pool: &AnyPool, username: &str, token: Option<&str>) -> Result<()> {
    let mut change = Change::begin(pool, username).await?;
    if let Some(token) = token {
        store::accounts::delete_session(change.db(), token).await?;
    }
    change.commit("logout", None, NoDetail {}).await
}

/// What `login.failed` records: the name tried, from where, and whether the account is
/// disabled (only when the password was right).
#[derive(Debug, Serialize)]
struct LoginFailed<'a> {
    username: &'a str,
    from: String,
    disabled: bool,
}

/// Checks a password, rate-limited per username and client address and per address (the
/// attempt is counted before the check); returns the new session. A disabled account is refused. Every failure is in the audit log.
pub async fn login(
    pool: &AnyPool,
    limiter: &LoginLimiter,
    username: &str,
    password: &str,
    peer: IpAddr,
) -> Result<NewSession> {
    if username.len() > MAX_USERNAME {
        return Err(AppError::BadRequest(format!(
            "username: at most {MAX_USERNAME} bytes"
        )));
    }
    if password.len() > MAX_PASSWORD_BYTES {
        return Err(AppError::BadRequest(format!(
            "password: at most {MAX_PASSWORD_BYTES} bytes"
        )));
    }
    let reservation = limiter
        .reserve(username, peer, Instant::now())
        .map_err(|retry_after| AppError::TooManyRequests {
            message: "too many attempts; wait a minute and try again".into(),
            retry_after,
        })?;
    let row = store::accounts::credentials(pool, username).await?;
    // Verify against a dummy hash for unknown users too, so timing does not reveal names.
    let phc = match &row {
        Some(c) => c.password_hash.clone(),
        None => dummy_hash().await?,
    };
    let ok = passwords::verify(password, &phc).await?;
    match (row, ok) {
        (Some(c), true) if !c.disabled => {
            limiter.succeeded(reservation);
            let from = peer.to_string();
            new_session(pool, c.id, username, c.role, Login::Password { from }).await
        }
        (row, ok) => {
            // Only someone who knows the password learns that the account is disabled.
            let disabled = ok && row.as_ref().is_some_and(|c| c.disabled);
            let change = Change::begin(pool, "anonymous:login").await?;
            change
                .commit(
                    "login.failed",
                    row.map(|c| format!("experimenter:{}", c.id)),
                    LoginFailed {
                        username,
                        from: peer.to_string(),
                        disabled,
                    },
                )
                .await?;
            Err(AppError::Forbidden(if disabled {
                "this account is disabled: ask an admin".into()
            } else {
                "wrong username or password".into()
            }))
        }
    }
}

/// Every account, for the admin.
pub async fn list(pool: &AnyPool) -> Result<Vec<Account>> {
    let mut db = pool.acquire().await?;
    store::accounts::accounts(&mut db).await
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn site_limits_are_served_sites_sorted_once() {
        let served = ["lab-b", "lab-a"];
        let limit = |sites: &[&str]| {
            let sites: Vec<String> = sites.iter().map(|s| s.to_string()).collect();
            SiteLimit {
                sites: &sites,
                served: &served,
            }
            .checked()
        };
        assert_eq!(
            limit(&["lab-b", "lab-a", "lab-b"]).unwrap(),
            ["lab-a", "lab-b"]
        );
        for bad in [&[][..], &["lab-c"], &["lab-a", "LAB-B"]] {
            let e = limit(bad).unwrap_err().to_string();
            assert!(
                e.starts_with("sites: ") && e.contains("lab-b, lab-a"),
                "{bad:?}: {e}"
            );
        }
    }

    #[test]
    fn sites_are_named_in_words() {
        assert_eq!(sites_words(&["a"]), r#"site "a""#);
        assert_eq!(sites_words(&["a", "b", "c"]), r#"sites "a", "b" and "c""#);
    }

    #[test]
    fn a_login_records_how_the_session_began() {
        let text = |how: Login| store::json_text(&how).unwrap();
        assert_eq!(text(Login::Setup), r#"{"after":"setup"}"#);
        let from = "127.0.0.1".to_string();
        assert_eq!(text(Login::Password { from }), r#"{"from":"127.0.0.1"}"#);
    }
}
