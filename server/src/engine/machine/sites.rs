//! The sites one server serves (`serve --site`): each lab's machine with its own controller
//! link, by name. A station belongs to one site; a trial runs on its subject's stations'
//! site and records it; a lost controller files only its own site's trials; an E-stop
//! stops one site or all of them. Without `--site` the server has one site, [`DEFAULT`].

use std::sync::Arc;

use tokio::sync::broadcast;

use super::controller_link::{ControllerEvent, ControllerLink};
use super::estop_latch::EStopLatch;
use crate::error::{AppError, Result};

/// The name of the one site of a server started without `--site`.
pub const DEFAULT: &str = "main";

/// The longest site name (it is recorded with every trial and shown on the dashboard).
const MAX_NAME: usize = 40;

/// A site's name as `--site` and the API take it, or why it is not one: the rule of every
/// name (`engine::name_rule`), in a stricter alphabet.
pub fn check_name(name: &str) -> std::result::Result<(), String> {
    let ok = crate::engine::name_rule("site name", name, 1, MAX_NAME).is_ok()
        && name.starts_with(|c: char| c.is_ascii_lowercase() || c.is_ascii_digit())
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '-');
    if ok {
        Ok(())
    } else {
        Err(format!(
            "site name {name:?}: 1 to {MAX_NAME} of a-z, 0-9 and '-', starting with a letter or digit"
        ))
    }
}

/// Every site's controller link, in the order they were given (the first is the site of
/// stations paired before sites existed, of subjects at no station, and of bench runs).
#[derive(Clone, Debug)]
pub struct Sites {
    links: Arc<[ControllerLink]>,
    events: broadcast::Sender<ControllerEvent>,
    /// The server's E-stop latch of every site.
    latch: EStopLatch,
}

impl Sites {
    /// `links` (at least one, names unique) all telling `events`, all obeying `latch`.
    pub fn new(
        links: Vec<ControllerLink>,
        events: broadcast::Sender<ControllerEvent>,
        latch: EStopLatch,
    ) -> Self {
        assert!(!links.is_empty(), "a server has at least one site");
        Self {
            links: links.into(),
            events,
            latch,
        }
    }

    /// The server's E-stop latch.
    pub fn latch(&self) -> &EStopLatch {
        &self.latch
    }

    /// The first site's link.
    pub fn first(&self) -> &ControllerLink {
        &self.links[0]
    }

    pub fn all(&self) -> &[ControllerLink] {
        &self.links
    }

    /// The link of the site named `name`: a 400 naming the sites there are otherwise.
    pub fn named(&self, name: &str) -> Result<&ControllerLink> {
        self.links.iter().find(|l| l.site() == name).ok_or_else(|| {
            AppError::BadRequest(format!(
                "site: no site {name:?} here; the sites are {}",
                self.names().join(", ")
            ))
        })
    }

    /// The link of a stored site (a station's or a trial's): the first site for none (stored
    /// before sites existed) and, for a site this server no longer serves, `None`.
    pub fn stored(&self, site: Option<&str>) -> Option<&ControllerLink> {
        match site {
            None => Some(self.first()),
            Some(name) => self.links.iter().find(|l| l.site() == name),
        }
    }

    /// The name of a stored site: the first site's for none.
    pub fn name_of<'a>(&'a self, stored: Option<&'a str>) -> &'a str {
        stored.unwrap_or_else(|| self.first().site())
    }

    pub fn names(&self) -> Vec<&str> {
        self.links.iter().map(ControllerLink::site).collect()
    }

    /// Every site's events.
    pub fn subscribe(&self) -> broadcast::Receiver<ControllerEvent> {
        self.events.subscribe()
    }

    /// Tells every listener (station and dashboard sockets) about an event.
    pub fn emit(&self, ev: ControllerEvent) {
        let _ = self.events.send(ev);
    }

    /// Whether every site's controller is connected.
    pub fn all_connected(&self) -> bool {
        self.links.iter().all(ControllerLink::is_connected)
    }

    /// Whether any site is stopped: by the server's latch or its controller's.
    pub fn any_latched(&self) -> bool {
        self.links.iter().any(ControllerLink::stopped)
    }
}

#[cfg(test)]
mod tests {
    use super::check_name;

    #[test]
    fn site_names_are_short_lowercase_words() {
        for good in ["main", "delft-2", "0lab", &"a".repeat(40)] {
            assert!(check_name(good).is_ok(), "{good}");
        }
        for bad in [
            "",
            "-lab",
            "Delft",
            "lab 2",
            "lab_2",
            "läb",
            &"a".repeat(41),
        ] {
            let e = check_name(bad).unwrap_err();
            assert!(e.contains("a-z, 0-9 and '-'"), "{bad}: {e}");
        }
    }
}
