//! What a command waiting for its peers can tell about them: on DDS what
//! discovery found so far, for the progress lines of long waits.

use std::collections::{HashMap, HashSet};

use courier::{EndpointInfo, Guid, SessionEvent};

use crate::stop::count;

/// Participants and endpoints discovered so far (DDS).
#[derive(Default)]
pub struct Discovery {
    participants: HashSet<[u8; 12]>,
    publications: HashMap<Guid, EndpointInfo>,
    subscriptions: HashMap<Guid, EndpointInfo>,
}

impl Discovery {
    /// Takes a session event into account.
    pub fn update(&mut self, e: &SessionEvent) {
        match e {
            SessionEvent::ParticipantFound(p) | SessionEvent::ParticipantChanged(p) => {
                self.participants.insert(p.guid.prefix());
            }
            SessionEvent::ParticipantLost { guid, .. } => {
                self.participants.remove(&guid.prefix());
                self.publications.retain(|g, _| !g.is_of(guid.prefix()));
                self.subscriptions.retain(|g, _| !g.is_of(guid.prefix()));
            }
            SessionEvent::PublicationFound(p) | SessionEvent::PublicationChanged(p) => {
                self.publications.insert(p.guid, (**p).clone());
            }
            SessionEvent::PublicationLost(g) => {
                self.publications.remove(g);
            }
            SessionEvent::SubscriptionFound(p) | SessionEvent::SubscriptionChanged(p) => {
                self.subscriptions.insert(p.guid, (**p).clone());
            }
            SessionEvent::SubscriptionLost(g) => {
                self.subscriptions.remove(g);
            }
            _ => {}
        }
    }

    fn of<'a>(m: &'a HashMap<Guid, EndpointInfo>, topic: &str) -> Vec<&'a EndpointInfo> {
        m.values().filter(|e| e.topic == topic).collect()
    }

    /// What was found, for a progress line: `2 participants, 1 publication
    /// of "chatter" (courier::Ping)`, with `what` the kind of endpoint the
    /// command waits for.
    pub fn summary(&self, topic: &str, publications: bool) -> String {
        let (m, kind) = if publications {
            (&self.publications, "publication")
        } else {
            (&self.subscriptions, "subscription")
        };
        let eps = Self::of(m, topic);
        let mut types: Vec<&str> = eps.iter().map(|e| e.type_name.as_str()).collect();
        types.sort_unstable();
        types.dedup();
        let types = if types.is_empty() {
            String::new()
        } else {
            format!(" ({})", types.join(", "))
        };
        format!(
            "{} found, {} of {topic:?}{types}",
            count(self.participants.len() as u64, "participant"),
            count(eps.len() as u64, kind),
        )
    }
}
