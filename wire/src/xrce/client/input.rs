//! What the client does with a message from the agent.

use std::time::Instant;

use super::super::object::{ActivityInfo, ObjectInfo};
use super::super::session::InputError;
use super::super::stream::FragmentError;
use super::super::submessage::{
    flags, Data, Info, Payload, Status, StatusAgent, Submessage, TimestampReply,
};
use super::super::types::{
    BaseObjectRequest, ObjectId, ObjectKind, RequestId, ResultStatus, StreamId,
};
use super::super::Message;
use super::{
    time_ns, Client, ConnectError, Event, LostReason, PendingKind, SampleIdentity, State,
    StatusError,
};

impl Client {
    /// Takes one message from the agent.
    pub fn handle_input(&mut self, bytes: &[u8], now: Instant) -> Result<(), InputError> {
        let now = self.tick(now);
        let msg = Message::decode(bytes)?;
        let h = msg.header;
        let own = self.cfg.session_id;
        let outside = h.session_id == own & 0x80 && h.session_id != own;
        if h.session_id != own && !outside {
            return Err(InputError::WrongSession {
                expected: own,
                got: h.session_id,
            });
        }
        if let Some(k) = h.client_key.filter(|k| *k != self.cfg.client_key) {
            return Err(InputError::WrongClientKey {
                expected: self.cfg.client_key.into(),
                got: k.into(),
            });
        }
        let streams_open = matches!(
            self.state,
            State::Connected | State::Lost | State::Deleting { .. }
        );
        if outside || !streams_open {
            // only answers to what was sent outside the streams
            if h.stream_id != super::StreamId::NONE {
                return Err(InputError::Unsolicited {
                    what: "stream message outside a session",
                });
            }
            let mut first = Ok(());
            for sub in msg.submessages {
                let r = match sub.payload {
                    Payload::Info(i) => self.on_info(i, now),
                    Payload::StatusAgent(s) if !outside => self.on_status_agent(s, now),
                    Payload::Status(s) if !outside => self.on_session_status(s),
                    p => Err(InputError::Unexpected {
                        what: p.id().name(),
                        stream: 0,
                    }),
                };
                first = first.and(r);
            }
            return first;
        }
        // an agent that answers a ping without knowing the session has
        // not been heard: it lost the session (see `on_info`)
        let forgot_us = !msg.submessages.is_empty()
            && msg.submessages.iter().all(
                |s| matches!(&s.payload, Payload::Info(i) if i.result.implementation_status == 0),
            );
        if !forgot_us {
            self.heard(now);
        }
        let arrival = self.streams.receive(msg, bytes.len(), now);
        for e in &arrival.errors {
            // (each one: a sample lost to its reader, which only the first
            // error returned would leave unsaid when it is not first)
            if let InputError::Fragment(FragmentError::TooLarge { max, object }) = e {
                self.events.push_back(Event::TooLarge {
                    object: *object,
                    max: *max,
                });
            }
        }
        let mut first = arrival.errors.into_iter().next().map_or(Ok(()), Err);
        for (stream, sub) in arrival.subs {
            let r = self.on_submessage(stream, sub, now);
            first = first.and(r);
        }
        self.streams.control.extend(arrival.replies);
        for tag in self.streams.take_acked() {
            self.unconfirmed.acked(tag);
            self.events.push_back(Event::WriteAcked(RequestId(tag)));
        }
        first
    }

    fn heard(&mut self, now: Instant) {
        self.last_heard = Some(now);
        if self.state == State::Lost {
            self.state = State::Connected;
            self.events.push_back(Event::AgentBack);
        }
    }

    fn on_submessage(
        &mut self,
        stream: StreamId,
        sub: Submessage,
        now: Instant,
    ) -> Result<(), InputError> {
        let format = sub.data_format();
        match sub.payload {
            Payload::Status(s) if stream == StreamId::NONE => self.on_session_status(s),
            Payload::Status(s) => self.on_status(s),
            Payload::StatusAgent(_) => Err(InputError::Unsolicited {
                what: "STATUS_AGENT",
            }),
            Payload::Info(i) => self.on_info(i, now),
            Payload::Data(d) => self.on_data(stream, format, d),
            Payload::TimestampReply(t) => self.on_timestamp_reply(t, now),
            Payload::GetInfo(g) => {
                let info = Info {
                    request: BaseObjectRequest::new(g.request.request_id.0, ObjectId::INVALID),
                    result: ResultStatus::default(),
                    info: ObjectInfo::default(),
                };
                let _ = self
                    .streams
                    .send_control(Submessage::new(Payload::Info(info)));
                Ok(())
            }
            p => Err(InputError::Unexpected {
                what: p.id().name(),
                stream: stream.0,
            }),
        }
    }

    fn on_status_agent(&mut self, s: StatusAgent, now: Instant) -> Result<(), InputError> {
        if !matches!(self.state, State::Connecting { .. }) {
            return Err(InputError::Unsolicited {
                what: "STATUS_AGENT",
            });
        }
        if s.result.status.is_ok() {
            self.state = State::Connected;
            self.streams.reset();
            self.last_heard = Some(now);
            self.last_ping = None;
            self.agent = Some(s.agent.clone());
            self.events.push_back(Event::Connected { agent: s.agent });
        } else {
            self.state = State::Idle;
            self.events
                .push_back(Event::ConnectFailed(ConnectError::Refused(s.result.status)));
        }
        Ok(())
    }

    fn on_session_status(&mut self, s: Status) -> Result<(), InputError> {
        if !matches!(self.state, State::Deleting { .. })
            || s.request.request_id != RequestId::LOGOUT
        {
            return Err(InputError::Unsolicited { what: "STATUS" });
        }
        self.state = State::Closed;
        self.streams.reset();
        self.events
            .push_back(Event::SessionDeleted { confirmed: true });
        Ok(())
    }

    fn on_status(&mut self, s: Status) -> Result<(), InputError> {
        let req = s.request.request_id.0;
        let object = s.request.object_id;
        let code = s.result.status;
        let result = if code.is_ok() {
            Ok(code)
        } else {
            Err(StatusError(code))
        };
        match self.pending.get(&req) {
            Some(&(o, kind)) if o == object => {
                self.pending.remove(&req);
                if kind == PendingKind::Create && result.is_err() {
                    self.objects.retain(|d| d.id != object);
                }
            }
            _ => {
                let read = self
                    .reads
                    .iter()
                    .find(|(_, r)| r.request == req && r.read.request.object_id == object)
                    .map(|(k, _)| *k);
                match read {
                    Some(k) => {
                        if result.is_err() {
                            self.reads.remove(&k);
                        }
                    }
                    // the agent refused a write (WRITE_DATA of an object it
                    // does not have): reported as the object's status
                    None if result.is_err() && self.objects.iter().any(|d| d.id == object) => {}
                    None => return Err(InputError::Unsolicited { what: "STATUS" }),
                }
            }
        }
        self.events.push_back(Event::Status {
            request: RequestId(req),
            object,
            result,
        });
        Ok(())
    }

    fn on_info(&mut self, i: Info, now: Instant) -> Result<(), InputError> {
        if i.request.request_id != RequestId::PING {
            return Err(InputError::Unsolicited { what: "INFO" });
        }
        let available = matches!(
            i.info.activity,
            Some(ActivityInfo::Agent { availability, .. }) if availability > 0
        );
        if !available {
            return Ok(());
        }
        let rtt = self
            .ping_sent
            .take()
            .map(|t| now.saturating_duration_since(t));
        let in_session = i.result.implementation_status != 0;
        if self.in_session() {
            if in_session {
                self.heard(now);
            } else if self.state == State::Connected {
                self.state = State::Lost;
                self.events
                    .push_back(Event::AgentLost(LostReason::SessionUnknown));
            }
        }
        self.events.push_back(Event::Pong { in_session, rtt });
        Ok(())
    }

    fn on_data(&mut self, stream: StreamId, format: u8, d: Data) -> Result<(), InputError> {
        if format != flags::FORMAT_DATA {
            return Err(InputError::DataFormat(format));
        }
        let object = d.request.object_id;
        let request = d.request.request_id;
        let short = |needed| InputError::ShortData {
            object: object.0,
            len: d.data.len(),
            needed,
        };
        let event = match object.kind() {
            Some(ObjectKind::DataReader) => Event::Data {
                reader: object,
                request,
                stream,
                data: d.data,
            },
            Some(ObjectKind::Requester) => {
                let (Some(&[r0, r1]), Some(rest)) = (d.data.get(..2), d.data.get(4..)) else {
                    return Err(short(4));
                };
                Event::Reply {
                    requester: object,
                    request: RequestId(u16::from_be_bytes([r0, r1])),
                    data: rest.to_vec(),
                }
            }
            Some(ObjectKind::Replier) => {
                let (Some(identity), Some(rest)) = (
                    SampleIdentity::from_bytes(&d.data),
                    d.data.get(SampleIdentity::LEN..),
                ) else {
                    return Err(short(SampleIdentity::LEN));
                };
                Event::Request {
                    replier: object,
                    request,
                    identity,
                    data: rest.to_vec(),
                }
            }
            _ => {
                return Err(InputError::Unexpected {
                    what: "DATA for an object that does not read",
                    stream: stream.0,
                })
            }
        };
        self.events.push_back(event);
        Ok(())
    }

    fn on_timestamp_reply(&mut self, t: TimestampReply, now: Instant) -> Result<(), InputError> {
        let Some((sent_at, sent_ns, sent)) = self.sync.filter(|s| s.2 == t.originate) else {
            return Err(InputError::Unsolicited {
                what: "TIMESTAMP_REPLY",
            });
        };
        self.sync = None;
        let rtt = now.saturating_duration_since(sent_at);
        let t3 = i128::from(sent_ns) + i128::try_from(rtt.as_nanos()).unwrap_or(0);
        let t0 = i128::from(time_ns(sent));
        let (t1, t2) = (
            i128::from(time_ns(t.receive)),
            i128::from(time_ns(t.transmit)),
        );
        let offset = ((t0 + t3) - (t1 + t2)) / 2;
        let offset_ns =
            i64::try_from(offset).unwrap_or(if offset < 0 { i64::MIN } else { i64::MAX });
        self.offset_ns = Some(offset_ns);
        self.events.push_back(Event::TimeSynced { offset_ns, rtt });
        Ok(())
    }
}
