//! Keyed or not as a topic's readers are: a DDS reader matches only a
//! writer of its own kind (keyed types' endpoints are `WITH_KEY`), and
//! the types the CLI writes (a `--format` layout, a recording's channel)
//! say nothing of keys. A publication whose topic's known readers of its
//! type all want the other kind is opened again as they want.

use courier::{Handle, PubId, PublicationQos, Session, TypeInfo};

use crate::Result;

/// A publication the CLI writes: its topic, and the type and QoS it was
/// opened with (to open it again).
pub struct Publication {
    pub id: PubId,
    pub topic: String,
    pub ty: TypeInfo,
    qos: PublicationQos,
}

impl Publication {
    /// Opens `topic` as `ty`.
    pub async fn open(
        s: &Session,
        topic: &str,
        ty: TypeInfo,
        qos: &PublicationQos,
    ) -> Result<Publication> {
        let id = s.backend().open_publication(topic, &ty, qos).await?;
        Ok(Publication {
            id,
            topic: topic.to_string(),
            ty,
            qos: qos.clone(),
        })
    }

    /// If every reader of its topic (of its type) that discovery knows
    /// wants the other kind, opens the publication again as that kind,
    /// closes the old one, and returns whether it is keyed now. Nothing off
    /// DDS, without readers, or when some reader already matches.
    pub async fn key_as_readers(&mut self, s: &Session) -> Result<Option<bool>> {
        let Ok(dds) = s.dds() else {
            return Ok(None);
        };
        let readers = dds.readers_of(&self.topic).await?;
        let mut kinds = readers
            .iter()
            .filter(|r| r.type_name == self.ty.type_name)
            .map(courier::EndpointInfo::keyed);
        let Some(keyed) = kinds.next() else {
            return Ok(None);
        };
        if keyed == self.ty.keyed || kinds.any(|k| k != keyed) {
            return Ok(None); // they match already, or some would stop matching
        }
        let b = s.backend();
        let mut ty = self.ty.clone();
        ty.keyed = keyed;
        let id = b.open_publication(&self.topic, &ty, &self.qos).await?;
        b.close_handle(Handle::Publication(self.id));
        self.id = id;
        self.ty = ty;
        Ok(Some(keyed))
    }

    /// Closes it.
    pub fn close(&self, s: &Session) {
        s.backend().close_handle(Handle::Publication(self.id));
    }
}

/// How a line says which kind a publication became.
pub fn kind_word(keyed: bool) -> &'static str {
    if keyed {
        "keyed"
    } else {
        "not keyed"
    }
}
