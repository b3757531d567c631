//! ROS 2 over DDS: the names ROS 2 gives DDS topics and types
//! ([`names`]), its graph topic `ros_discovery_info` ([`graph`]) and what a
//! participant learns from it ([`cache`]), as the DDS-based rmw
//! implementations (rmw_fastrtps, rmw_cyclonedds) use them.
//!
//! ```
//! use courier_wire::ros2::names::{dds_topic, dds_type, ros_topic, Kind, Node};
//! let node = Node::new("/robot", "talker").unwrap();
//! let name = node.expand("chatter").unwrap();
//! assert_eq!(name, "/robot/chatter");
//! assert_eq!(dds_topic(&name, Kind::Topic).unwrap(), "rt/robot/chatter");
//! assert_eq!(dds_topic("/add", Kind::Request).unwrap(), "rq/addRequest");
//! assert_eq!(ros_topic("rr/addReply"), Some(("/add".into(), Kind::Reply)));
//! assert_eq!(
//!     dds_type("example_interfaces/srv/AddTwoInts", Kind::Reply).unwrap(),
//!     "example_interfaces::srv::dds_::AddTwoInts_Response_"
//! );
//! ```

pub mod cache;
pub mod graph;
pub mod names;
