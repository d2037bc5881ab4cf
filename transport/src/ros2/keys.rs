//! rmw_zenoh's names on the Zenoh side: topic key expressions, liveliness tokens and the
//! attachment every publication carries (ros2/rmw_zenoh `docs/design.md`, sections "Topic and
//! Service name mapping to Zenoh key expressions", "Graph Cache" and "Publishers"; the QoS
//! chunk follows `qos_to_keyexpr` in `liveliness_utils.cpp`).
//!
//! * Topic: `<domain_id>/<fully qualified name without the leading />/<DDS type name>/<type
//!   hash>`, e.g. `0/h4/measured_cp/geometry_msgs::msg::dds_::PoseStamped_/RIHS01_10f3...`.
//!   Humble's rmw_zenoh puts the constant [`HUMBLE_TYPE_HASH`] where the hash goes.
//! * Node token: `@ros2_lv/<domain_id>/<session id>/<node id>/<node id>/NN/<enclave>/<namespace>/<node name>`.
//! * Endpoint token: `@ros2_lv/<domain_id>/<session id>/<node id>/<entity id>/<MP|MS|SS|SC>/<enclave>/<namespace>/<node name>/<topic>/<DDS type name>/<type hash>/<qos>`,
//!   where enclave, namespace and topic are *mangled*: every `/` becomes `%` (so the root
//!   namespace `/` is `%` and `/h4/measured_cp` is `%h4%measured_cp`).
//! * Attachment: 33 bytes, sequence number (i64 LE), source timestamp (ns since the UNIX epoch,
//!   i64 LE), GID length (1 byte, 16), GID (16 bytes).

use std::fmt;

use super::type_hash::{self, TypeHash, TypeHashError};

/// Prefix of every rmw_zenoh liveliness token (a Zenoh hermetic namespace).
pub const ADMIN_SPACE: &str = "@ros2_lv";

/// What Humble's rmw_zenoh writes where a type hash goes (Humble has no type hashes).
pub const HUMBLE_TYPE_HASH: &str = "TypeHashNotSupported";

/// Why a name or key expression could not be built.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    /// Not a valid fully qualified ROS name (topic or namespace).
    #[error("{name:?} is not a valid fully qualified ROS name: {reason}")]
    InvalidName {
        /// The name.
        name: String,
        /// The rule it breaks.
        reason: &'static str,
    },
    /// Not a valid node name (letters, digits and `_`, not starting with a digit).
    #[error("{name:?} is not a valid ROS node name")]
    InvalidNodeName {
        /// The name.
        name: String,
    },
    /// Not a `pkg/msg/Name` type name.
    #[error("{name:?} is not a ROS type name of the form pkg/msg/Name")]
    InvalidTypeName {
        /// The name.
        name: String,
    },
    /// Not a Zenoh session id in its text form (lowercase hex, 1 to 32 digits).
    #[error("{zid:?} is not a Zenoh session id (lowercase hex)")]
    InvalidZid {
        /// The text.
        zid: String,
    },
    /// The type hash could not be computed.
    #[error(transparent)]
    TypeHash(#[from] TypeHashError),
}

fn is_token_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || c == '_'
}

/// Checks a fully qualified topic name or namespace: starts with `/`, tokens of letters,
/// digits and `_` separated by single `/`, no token starting with a digit, no trailing `/`.
/// `/` alone (the root namespace) is accepted only if `allow_root`.
pub fn validate_fully_qualified_name(name: &str, allow_root: bool) -> Result<(), KeyError> {
    let invalid = |reason| KeyError::InvalidName {
        name: name.to_owned(),
        reason,
    };
    let Some(rest) = name.strip_prefix('/') else {
        return Err(invalid("it must start with /"));
    };
    if rest.is_empty() {
        return if allow_root {
            Ok(())
        } else {
            Err(invalid("it has no name after /"))
        };
    }
    for token in rest.split('/') {
        if token.is_empty() {
            return Err(invalid("it has an empty token (// or a trailing /)"));
        }
        if !token.chars().all(is_token_char) {
            return Err(invalid("only letters, digits, _ and / are allowed"));
        }
        if token.starts_with(|c: char| c.is_ascii_digit()) {
            return Err(invalid("a token starts with a digit"));
        }
    }
    Ok(())
}

/// Checks a node name: letters, digits and `_`, not empty, not starting with a digit.
pub fn validate_node_name(name: &str) -> Result<(), KeyError> {
    let ok = !name.is_empty()
        && name.chars().all(is_token_char)
        && !name.starts_with(|c: char| c.is_ascii_digit());
    if ok {
        Ok(())
    } else {
        Err(KeyError::InvalidNodeName {
            name: name.to_owned(),
        })
    }
}

/// The DDS type name of a ROS type: `pkg/msg/Name` → `pkg::msg::dds_::Name_`.
pub fn dds_type_name(type_name: &str) -> Result<String, KeyError> {
    let invalid = || KeyError::InvalidTypeName {
        name: type_name.to_owned(),
    };
    let mut parts = type_name.split('/');
    let (Some(package), Some(kind), Some(name), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(invalid());
    };
    let valid = |s: &str| !s.is_empty() && s.chars().all(is_token_char);
    if !valid(package) || !valid(name) || !matches!(kind, "msg" | "srv" | "action") {
        return Err(invalid());
    }
    Ok(format!("{package}::{kind}::dds_::{name}_"))
}

/// `/` → `%`, rmw_zenoh's `mangle_name`.
pub fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// Which ROS 2 distribution's rmw_zenoh the keys are for.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Distro {
    /// Humble: [`HUMBLE_TYPE_HASH`] instead of a type hash.
    Humble,
    /// Jazzy and every distribution with REP 2011 type hashes (Iron, Kilted, Rolling): the
    /// RIHS01 hash.
    #[default]
    Jazzy,
}

/// What goes in the type hash field of keys and tokens.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TypeHashField {
    /// `RIHS01_<hex>`.
    Rihs01(TypeHash),
    /// Humble: `TypeHashNotSupported`.
    NotSupported,
}

impl TypeHashField {
    /// The field for `type_name` (`pkg/msg/Name`) on `distro`.
    pub fn for_type(distro: Distro, type_name: &str) -> Result<Self, TypeHashError> {
        match distro {
            Distro::Humble => Ok(TypeHashField::NotSupported),
            Distro::Jazzy => type_hash::rihs01(type_name).map(TypeHashField::Rihs01),
        }
    }
}

impl fmt::Display for TypeHashField {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TypeHashField::Rihs01(h) => write!(f, "{h}"),
            TypeHashField::NotSupported => f.write_str(HUMBLE_TYPE_HASH),
        }
    }
}

/// A topic as rmw_zenoh names it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TopicInfo {
    /// Fully qualified name, e.g. `/h4/measured_cp`.
    pub fq_name: String,
    /// ROS type name, e.g. `geometry_msgs/msg/PoseStamped`.
    pub type_name: String,
    /// DDS type name, e.g. `geometry_msgs::msg::dds_::PoseStamped_`.
    pub dds_type_name: String,
    /// The type hash field.
    pub type_hash: TypeHashField,
    /// The endpoint's QoS (used in liveliness tokens only).
    pub qos: Qos,
}

impl TopicInfo {
    /// A topic of type `type_name` for `distro`'s rmw_zenoh.
    pub fn new(fq_name: &str, type_name: &str, distro: Distro, qos: Qos) -> Result<Self, KeyError> {
        validate_fully_qualified_name(fq_name, false)?;
        Ok(TopicInfo {
            fq_name: fq_name.to_owned(),
            type_name: type_name.to_owned(),
            dds_type_name: dds_type_name(type_name)?,
            type_hash: TypeHashField::for_type(distro, type_name)?,
            qos,
        })
    }

    /// The key expression data is published on: `<domain>/<name without leading />/<dds
    /// type>/<hash>`.
    pub fn key_expr(&self, domain_id: u32) -> String {
        let name = self.fq_name.strip_prefix('/').unwrap_or(&self.fq_name);
        format!(
            "{domain_id}/{name}/{}/{}",
            self.dds_type_name, self.type_hash
        )
    }
}

/// Kinds of graph entity, as liveliness tokens spell them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum EntityKind {
    /// `NN`.
    Node,
    /// `MP`, message publisher.
    Publisher,
    /// `MS`, message subscription.
    Subscription,
    /// `SS`, service server.
    ServiceServer,
    /// `SC`, service client.
    ServiceClient,
}

impl EntityKind {
    /// The two letters.
    pub fn as_str(self) -> &'static str {
        match self {
            EntityKind::Node => "NN",
            EntityKind::Publisher => "MP",
            EntityKind::Subscription => "MS",
            EntityKind::ServiceServer => "SS",
            EntityKind::ServiceClient => "SC",
        }
    }
}

/// A node as its liveliness tokens describe it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NodeInfo {
    /// `ROS_DOMAIN_ID`.
    pub domain_id: u32,
    /// The Zenoh session id as text (`ZenohId`'s `Display`: lowercase hex).
    pub zid: String,
    /// The node's id within the session (rmw_zenoh counts entities of a context from 0).
    pub node_id: u64,
    /// SROS enclave, `/` when not set.
    pub enclave: String,
    /// Namespace, `/` for the root namespace.
    pub namespace: String,
    /// Node name.
    pub name: String,
}

impl NodeInfo {
    /// A node in `namespace` (`""` or `"/"` for the root) with the default enclave `/`.
    pub fn new(
        domain_id: u32,
        zid: &str,
        node_id: u64,
        namespace: &str,
        name: &str,
    ) -> Result<Self, KeyError> {
        let namespace = if namespace.is_empty() { "/" } else { namespace };
        validate_fully_qualified_name(namespace, true)?;
        validate_node_name(name)?;
        let zid_ok = !zid.is_empty()
            && zid.len() <= 32
            && zid.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'));
        if !zid_ok {
            return Err(KeyError::InvalidZid {
                zid: zid.to_owned(),
            });
        }
        Ok(NodeInfo {
            domain_id,
            zid: zid.to_owned(),
            node_id,
            enclave: "/".to_owned(),
            namespace: namespace.to_owned(),
            name: name.to_owned(),
        })
    }

    fn token_prefix(&self, entity_id: u64, kind: EntityKind) -> String {
        format!(
            "{ADMIN_SPACE}/{}/{}/{}/{entity_id}/{}/{}/{}/{}",
            self.domain_id,
            self.zid,
            self.node_id,
            kind.as_str(),
            mangle(&self.enclave),
            mangle(&self.namespace),
            mangle(&self.name),
        )
    }

    /// The node's own liveliness token (its id appears twice).
    pub fn node_token(&self) -> String {
        self.token_prefix(self.node_id, EntityKind::Node)
    }

    /// The liveliness token of an endpoint (`kind` other than [`EntityKind::Node`]) of this
    /// node on `topic`, with id `entity_id` (unique within the session).
    pub fn endpoint_token(&self, entity_id: u64, kind: EntityKind, topic: &TopicInfo) -> String {
        format!(
            "{}/{}/{}/{}/{}",
            self.token_prefix(entity_id, kind),
            mangle(&topic.fq_name),
            mangle(&topic.dds_type_name),
            mangle(&topic.type_hash.to_string()),
            topic.qos.keyexpr()
        )
    }
}

/// QoS reliability (`rmw_qos_reliability_policy_e` values).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Reliability {
    /// 1.
    Reliable,
    /// 2.
    BestEffort,
}

/// QoS durability (`rmw_qos_durability_policy_e` values).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Durability {
    /// 1.
    TransientLocal,
    /// 2.
    Volatile,
}

/// QoS history (`rmw_qos_history_policy_e` values).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum History {
    /// 1.
    KeepLast,
    /// 2.
    KeepAll,
}

/// QoS liveliness (`rmw_qos_liveliness_policy_e` values).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Liveliness {
    /// 1.
    Automatic,
    /// 3.
    ManualByTopic,
}

impl Reliability {
    fn rmw_value(self) -> u8 {
        match self {
            Reliability::Reliable => 1,
            Reliability::BestEffort => 2,
        }
    }
}

impl Durability {
    fn rmw_value(self) -> u8 {
        match self {
            Durability::TransientLocal => 1,
            Durability::Volatile => 2,
        }
    }
}

impl History {
    fn rmw_value(self) -> u8 {
        match self {
            History::KeepLast => 1,
            History::KeepAll => 2,
        }
    }
}

impl Liveliness {
    fn rmw_value(self) -> u8 {
        match self {
            Liveliness::Automatic => 1,
            Liveliness::ManualByTopic => 3,
        }
    }
}

/// A QoS duration (`rmw_time_t`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct QosDuration {
    /// Seconds.
    pub sec: u64,
    /// Nanoseconds.
    pub nsec: u64,
}

impl QosDuration {
    /// `RMW_DURATION_INFINITE`: {9223372036 s, 854775807 ns}.
    pub const INFINITE: QosDuration = QosDuration {
        sec: 9_223_372_036,
        nsec: 854_775_807,
    };
}

/// The QoS of an endpoint, as far as rmw_zenoh's liveliness tokens carry it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Qos {
    /// Reliability.
    pub reliability: Reliability,
    /// Durability.
    pub durability: Durability,
    /// History.
    pub history: History,
    /// History depth (KEEP_LAST).
    pub depth: u64,
    /// Deadline.
    pub deadline: QosDuration,
    /// Lifespan.
    pub lifespan: QosDuration,
    /// Liveliness.
    pub liveliness: Liveliness,
    /// Liveliness lease duration.
    pub liveliness_lease: QosDuration,
}

impl Default for Qos {
    fn default() -> Self {
        Self::RMW_ZENOH_DEFAULT
    }
}

impl Qos {
    /// rmw_zenoh's defaults (`qos.cpp`): reliable, volatile, keep last 42, infinite durations,
    /// automatic liveliness. Components equal to these are left empty in the token.
    pub const RMW_ZENOH_DEFAULT: Qos = Qos {
        reliability: Reliability::Reliable,
        durability: Durability::Volatile,
        history: History::KeepLast,
        depth: 42,
        deadline: QosDuration::INFINITE,
        lifespan: QosDuration::INFINITE,
        liveliness: Liveliness::Automatic,
        liveliness_lease: QosDuration::INFINITE,
    };

    /// The defaults with KEEP_LAST `depth` (the `rclcpp::QoS(depth)` most nodes use).
    pub fn keep_last(depth: u64) -> Self {
        Qos {
            depth,
            ..Self::RMW_ZENOH_DEFAULT
        }
    }

    /// The token's QoS chunk, `qos_to_keyexpr`:
    /// `<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<lease s>,<ns>`,
    /// each component empty when it equals [`Qos::RMW_ZENOH_DEFAULT`]'s. Keep last 7 is
    /// `::,7:,:,:,,`.
    pub fn keyexpr(&self) -> String {
        fn part<T: PartialEq + ToString>(value: T, default: T) -> String {
            if value == default {
                String::new()
            } else {
                value.to_string()
            }
        }
        let d = Self::RMW_ZENOH_DEFAULT;
        format!(
            "{}:{}:{},{}:{},{}:{},{}:{},{},{}",
            part(self.reliability.rmw_value(), d.reliability.rmw_value()),
            part(self.durability.rmw_value(), d.durability.rmw_value()),
            part(self.history.rmw_value(), d.history.rmw_value()),
            part(self.depth, d.depth),
            part(self.deadline.sec, d.deadline.sec),
            part(self.deadline.nsec, d.deadline.nsec),
            part(self.lifespan.sec, d.lifespan.sec),
            part(self.lifespan.nsec, d.lifespan.nsec),
            part(self.liveliness.rmw_value(), d.liveliness.rmw_value()),
            part(self.liveliness_lease.sec, d.liveliness_lease.sec),
            part(self.liveliness_lease.nsec, d.liveliness_lease.nsec),
        )
    }
}

/// Bytes in a publication's attachment.
pub const ATTACHMENT_LEN: usize = 33;

/// Bytes in an rmw_zenoh GID (16 on every distribution, Humble included).
pub const GID_LEN: usize = 16;

/// Why an attachment could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AttachmentError {
    /// Not 33 bytes.
    #[error("attachment of {len_bytes} bytes, expected 33")]
    WrongLength {
        /// Its length.
        len_bytes: usize,
    },
    /// The GID length byte is not 16.
    #[error("attachment GID length {gid_len_bytes}, expected 16")]
    WrongGidLength {
        /// The length byte.
        gid_len_bytes: u8,
    },
}

/// The attachment rmw_zenoh puts on every publication (and service request and reply).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Attachment {
    /// The publisher's sequence number (rmw_zenoh starts at 1 and adds 1 per message).
    pub sequence_number: i64,
    /// Source timestamp, ns since the UNIX epoch.
    pub source_timestamp_ns: i64,
    /// The publisher's GID.
    pub gid: [u8; GID_LEN],
}

impl Attachment {
    /// The 33 bytes: sequence number (i64 LE), timestamp (i64 LE), 16, GID.
    pub fn to_bytes(self) -> [u8; ATTACHMENT_LEN] {
        let mut out = [0u8; ATTACHMENT_LEN];
        out[0..8].copy_from_slice(&self.sequence_number.to_le_bytes());
        out[8..16].copy_from_slice(&self.source_timestamp_ns.to_le_bytes());
        out[16] = GID_LEN as u8;
        out[17..33].copy_from_slice(&self.gid);
        out
    }

    /// Reads the 33 bytes back.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, AttachmentError> {
        let wrong = AttachmentError::WrongLength {
            len_bytes: bytes.len(),
        };
        let bytes: &[u8; ATTACHMENT_LEN] = bytes.try_into().map_err(|_| wrong)?;
        if usize::from(bytes[16]) != GID_LEN {
            return Err(AttachmentError::WrongGidLength {
                gid_len_bytes: bytes[16],
            });
        }
        let mut seq = [0u8; 8];
        seq.copy_from_slice(&bytes[0..8]);
        let mut stamp = [0u8; 8];
        stamp.copy_from_slice(&bytes[8..16]);
        let mut gid = [0u8; GID_LEN];
        gid.copy_from_slice(&bytes[17..33]);
        Ok(Attachment {
            sequence_number: i64::from_le_bytes(seq),
            source_timestamp_ns: i64::from_le_bytes(stamp),
            gid,
        })
    }

    /// The attachment as Zenoh bytes, for `put(...).attachment(...)`.
    #[cfg(feature = "zenoh")]
    pub fn to_zbytes(self) -> ::zenoh::bytes::ZBytes {
        ::zenoh::bytes::ZBytes::from(self.to_bytes())
    }

    /// Reads a received sample's attachment.
    #[cfg(feature = "zenoh")]
    pub fn from_zbytes(bytes: &::zenoh::bytes::ZBytes) -> Result<Self, AttachmentError> {
        Self::from_bytes(&bytes.to_bytes())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn names_are_validated() {
        assert!(validate_fully_qualified_name("/h4/measured_cp", false).is_ok());
        assert!(validate_fully_qualified_name("/", true).is_ok());
        for bad in [
            "", "/", "h4", "/h4/", "//h4", "/h4//x", "/4h", "/h-4", "/h4/ x",
        ] {
            assert!(
                validate_fully_qualified_name(bad, false).is_err(),
                "{bad:?} accepted"
            );
        }
        assert!(validate_node_name("h4_slave").is_ok());
        for bad in ["", "4x", "a/b", "a-b"] {
            assert!(validate_node_name(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn dds_type_names() {
        assert_eq!(
            dds_type_name("geometry_msgs/msg/PoseStamped").unwrap(),
            "geometry_msgs::msg::dds_::PoseStamped_"
        );
        assert_eq!(
            dds_type_name("example_interfaces/srv/AddTwoInts").unwrap(),
            "example_interfaces::srv::dds_::AddTwoInts_"
        );
        for bad in [
            "PoseStamped",
            "a/b",
            "a/msg/B/c",
            "a/foo/B",
            "/msg/B",
            "a/msg/",
        ] {
            assert!(dds_type_name(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn qos_chunks_match_design_md() {
        // The talker's publisher (depth 7) and the listener's subscription (depth 10).
        assert_eq!(Qos::keep_last(7).keyexpr(), "::,7:,:,:,,");
        assert_eq!(Qos::keep_last(10).keyexpr(), "::,10:,:,:,,");
        assert_eq!(Qos::RMW_ZENOH_DEFAULT.keyexpr(), "::,:,:,:,,");
        let sensor = Qos {
            reliability: Reliability::BestEffort,
            depth: 5,
            ..Qos::RMW_ZENOH_DEFAULT
        };
        assert_eq!(sensor.keyexpr(), "2::,5:,:,:,,");
        let latched = Qos {
            durability: Durability::TransientLocal,
            history: History::KeepAll,
            deadline: QosDuration { sec: 1, nsec: 0 },
            ..Qos::RMW_ZENOH_DEFAULT
        };
        assert_eq!(latched.keyexpr(), ":1:2,:1,0:,:,,");
    }

    #[test]
    fn attachment_layout() {
        let a = Attachment {
            sequence_number: 1,
            source_timestamp_ns: 0x0102_0304_0506_0708,
            gid: [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 0xff],
        };
        let bytes = a.to_bytes();
        assert_eq!(
            bytes,
            [
                1, 0, 0, 0, 0, 0, 0, 0, // sequence number
                8, 7, 6, 5, 4, 3, 2, 1,  // timestamp
                16, // GID length
                0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 0xff,
            ]
        );
        assert_eq!(Attachment::from_bytes(&bytes).unwrap(), a);
        assert_eq!(
            Attachment::from_bytes(&bytes[..32]),
            Err(AttachmentError::WrongLength { len_bytes: 32 })
        );
        let mut bad = bytes;
        bad[16] = 24;
        assert_eq!(
            Attachment::from_bytes(&bad),
            Err(AttachmentError::WrongGidLength { gid_len_bytes: 24 })
        );
    }
}
