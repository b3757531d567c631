//! ROS 2 names and the DDS names ROS 2 uses for them (the conventions
//! every DDS-based rmw follows: `rt/` topics, `rq/…Request` and
//! `rr/…Reply` service topics, `pkg::msg::dds_::Name_` type names).

use std::fmt;

/// What a DDS topic is to ROS 2.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    /// A topic (`rt/`).
    Topic,
    /// A service's request topic (`rq/…Request`).
    Request,
    /// A service's reply topic (`rr/…Reply`).
    Reply,
}

/// A ROS 2 name or type name that breaks ROS 2's rules.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{what} {name:?} is not a valid ROS 2 name: {why}")]
pub struct NameError {
    /// What was being checked (`topic name`, `namespace`, `node name`, `type name`).
    pub what: &'static str,
    /// The name as given.
    pub name: String,
    /// The rule it breaks.
    pub why: &'static str,
}

fn bad(what: &'static str, name: &str, why: &'static str) -> NameError {
    NameError {
        what,
        name: name.to_string(),
        why,
    }
}

/// Checks one token (between slashes): ROS 2 allows letters, digits and
/// underscores, not starting with a digit, and no repeated underscores.
fn check_token(what: &'static str, name: &str, token: &str) -> Result<(), NameError> {
    let Some(first) = token.chars().next() else {
        return Err(bad(
            what,
            name,
            "it has an empty part (`//` or a trailing `/`)",
        ));
    };
    if first.is_ascii_digit() {
        return Err(bad(what, name, "a part starts with a digit"));
    }
    if !token.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(bad(
            what,
            name,
            "only letters, digits, `_` and `/` are allowed",
        ));
    }
    if token.contains("__") {
        return Err(bad(what, name, "`__` is reserved"));
    }
    Ok(())
}

/// Checks a fully qualified name (`/a/b`, or `/` for a namespace).
fn check_absolute(what: &'static str, name: &str, root_ok: bool) -> Result<(), NameError> {
    let Some(rest) = name.strip_prefix('/') else {
        return Err(bad(what, name, "it must start with `/`"));
    };
    if rest.is_empty() {
        return if root_ok {
            Ok(())
        } else {
            Err(bad(what, name, "it is empty"))
        };
    }
    rest.split('/').try_for_each(|t| check_token(what, name, t))
}

/// A node's place in the graph: its namespace (`/` or `/a/b`) and name.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Node {
    namespace: String,
    name: String,
}

impl Node {
    /// A node named `name` in `namespace` (absolute; `""` means `/`).
    pub fn new(namespace: &str, name: &str) -> Result<Node, NameError> {
        let namespace = if namespace.is_empty() { "/" } else { namespace };
        check_absolute("namespace", namespace, true)?;
        if name.contains('/') {
            return Err(bad("node name", name, "it may not contain `/`"));
        }
        check_token("node name", name, name)?;
        Ok(Node {
            namespace: namespace.to_string(),
            name: name.to_string(),
        })
    }

    /// The namespace (`/` or `/a/b`).
    pub fn namespace(&self) -> &str {
        &self.namespace
    }

    /// The node's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// `name` expanded as ROS 2 expands a topic or service name of this
    /// node: absolute as given, `~/x` under the node, `x` under the
    /// namespace.
    pub fn expand(&self, name: &str) -> Result<String, NameError> {
        let base = self.namespace.trim_end_matches('/');
        let full = if name.starts_with('/') {
            name.to_string()
        } else if name == "~" {
            format!("{base}/{}", self.name)
        } else if let Some(rest) = name.strip_prefix("~/") {
            format!("{base}/{}/{rest}", self.name)
        } else {
            format!("{base}/{name}")
        };
        check_absolute("topic name", &full, false).map_err(|mut e| {
            e.name = name.to_string();
            e
        })?;
        Ok(full)
    }
}

impl fmt::Display for Node {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.namespace == "/" {
            write!(f, "/{}", self.name)
        } else {
            write!(f, "{}/{}", self.namespace, self.name)
        }
    }
}

/// The DDS topic name of fully qualified ROS 2 name `name` (`/chatter`)
/// used as `kind`: `rt/chatter`, `rq/addRequest`, `rr/addReply`.
pub fn dds_topic(name: &str, kind: Kind) -> Result<String, NameError> {
    check_absolute("topic name", name, false)?;
    let rest = &name[1..];
    Ok(match kind {
        Kind::Topic => format!("rt/{rest}"),
        Kind::Request => format!("rq/{rest}Request"),
        Kind::Reply => format!("rr/{rest}Reply"),
    })
}

/// The ROS 2 name and kind of DDS topic `topic`, if it is one ROS 2 uses
/// (`rt/chatter` → `/chatter`).
pub fn ros_topic(topic: &str) -> Option<(String, Kind)> {
    let (kind, rest) = if let Some(r) = topic.strip_prefix("rt/") {
        (Kind::Topic, r)
    } else if let Some(r) = topic.strip_prefix("rq/") {
        (Kind::Request, r.strip_suffix("Request")?)
    } else if let Some(r) = topic.strip_prefix("rr/") {
        (Kind::Reply, r.strip_suffix("Reply")?)
    } else {
        return None;
    };
    let name = format!("/{rest}");
    check_absolute("topic name", &name, false).ok()?;
    Some((name, kind))
}

/// The DDS type name of ROS 2 message type `ty` (`std_msgs/msg/String` →
/// `std_msgs::msg::dds_::String_`); for a service type
/// (`example_interfaces/srv/AddTwoInts`) give its request or reply kind
/// (`…::srv::dds_::AddTwoInts_Request_` / `_Response_`).
pub fn dds_type(ty: &str, kind: Kind) -> Result<String, NameError> {
    let parts: Vec<&str> = ty.split('/').collect();
    let [pkg, sub, name] = parts[..] else {
        return Err(bad(
            "type name",
            ty,
            "it must be `package/msg/Name` or `package/srv/Name`",
        ));
    };
    for t in [pkg, sub, name] {
        check_token("type name", ty, t)?;
    }
    match (sub, kind) {
        ("msg", Kind::Topic) => Ok(format!("{pkg}::msg::dds_::{name}_")),
        ("srv", Kind::Request) => Ok(format!("{pkg}::srv::dds_::{name}_Request_")),
        ("srv", Kind::Reply) => Ok(format!("{pkg}::srv::dds_::{name}_Response_")),
        ("msg", _) => Err(bad(
            "type name",
            ty,
            "a message type is for topics; services have `srv` types",
        )),
        ("srv", Kind::Topic) => Err(bad(
            "type name",
            ty,
            "a service type is for services; topics have `msg` types",
        )),
        _ => Err(bad(
            "type name",
            ty,
            "its middle part must be `msg` or `srv`",
        )),
    }
}

/// The ROS 2 type name of DDS type name `dds` (`std_msgs::msg::dds_::String_`
/// → `std_msgs/msg/String`; a service's request or reply type gives the
/// service type), if it follows ROS 2's convention.
pub fn ros_type(dds: &str) -> Option<(String, Kind)> {
    let parts: Vec<&str> = dds.split("::").collect();
    let [pkg, sub, "dds_", name] = parts[..] else {
        return None;
    };
    let name = name.strip_suffix('_')?;
    let (name, kind) = match sub {
        "msg" => (name, Kind::Topic),
        "srv" => {
            if let Some(n) = name.strip_suffix("_Request") {
                (n, Kind::Request)
            } else {
                (name.strip_suffix("_Response")?, Kind::Reply)
            }
        }
        _ => return None,
    };
    Some((format!("{pkg}/{sub}/{name}"), kind))
}
