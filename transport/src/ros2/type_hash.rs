//! Type descriptions (REP 2011, `type_description_interfaces`) of the messages this module
//! knows, and their RIHS01 type hashes.
//!
//! A type's hash is `RIHS01_` followed by the lowercase hex SHA-256 of a canonical JSON text of
//! its full type description, exactly as `rosidl_generator_type_description` computes it
//! (`calculate_type_hash`):
//!
//! * the object `{"type_description": T, "referenced_type_descriptions": [R, ...]}`, where `T`
//!   is the type itself and the `R` are every type it refers to, directly or through others,
//!   each once, sorted by type name;
//! * each individual description is `{"type_name": "pkg/msg/Name", "fields": [F, ...]}` with the
//!   fields in declaration order, each `{"name": ..., "type": {"type_id": ..., "capacity": ...,
//!   "string_capacity": ..., "nested_type_name": ...}}` (the `default_value` member is removed
//!   before hashing; constants are not part of a description);
//! * keys in that order, no whitespace but the separators `", "` and `": "` (Python's
//!   `json.dumps(..., separators=(', ', ': '))`), non-ASCII escaped (`ensure_ascii`).
//!
//! The descriptions below are transcribed from the `.msg` files; the hashes are computed from
//! them, never pasted. `transport/tests/ros2_vectors.rs` checks them against rosbags.

use std::collections::BTreeMap;
use std::fmt;

use sha2::{Digest, Sha256};

// Field type ids, from type_description_interfaces/msg/FieldType.msg.

/// Not set.
pub const FIELD_TYPE_NOT_SET: u8 = 0;
/// A nested type defined in another .msg/.idl file.
pub const FIELD_TYPE_NESTED_TYPE: u8 = 1;
/// `int8`.
pub const FIELD_TYPE_INT8: u8 = 2;
/// `uint8`.
pub const FIELD_TYPE_UINT8: u8 = 3;
/// `int16`.
pub const FIELD_TYPE_INT16: u8 = 4;
/// `uint16`.
pub const FIELD_TYPE_UINT16: u8 = 5;
/// `int32`.
pub const FIELD_TYPE_INT32: u8 = 6;
/// `uint32`.
pub const FIELD_TYPE_UINT32: u8 = 7;
/// `int64`.
pub const FIELD_TYPE_INT64: u8 = 8;
/// `uint64`.
pub const FIELD_TYPE_UINT64: u8 = 9;
/// `float32`.
pub const FIELD_TYPE_FLOAT: u8 = 10;
/// `float64`.
pub const FIELD_TYPE_DOUBLE: u8 = 11;
/// `long double`.
pub const FIELD_TYPE_LONG_DOUBLE: u8 = 12;
/// `char`.
pub const FIELD_TYPE_CHAR: u8 = 13;
/// `wchar`.
pub const FIELD_TYPE_WCHAR: u8 = 14;
/// `bool`.
pub const FIELD_TYPE_BOOLEAN: u8 = 15;
/// `byte` / `octet`.
pub const FIELD_TYPE_BYTE: u8 = 16;
/// `string`.
pub const FIELD_TYPE_STRING: u8 = 17;
/// `wstring`.
pub const FIELD_TYPE_WSTRING: u8 = 18;
/// Fixed-size `string`.
pub const FIELD_TYPE_FIXED_STRING: u8 = 19;
/// Fixed-size `wstring`.
pub const FIELD_TYPE_FIXED_WSTRING: u8 = 20;
/// `string<=N`.
pub const FIELD_TYPE_BOUNDED_STRING: u8 = 21;
/// `wstring<=N`.
pub const FIELD_TYPE_BOUNDED_WSTRING: u8 = 22;
/// Added to an element's id for a fixed-size array `T[N]` (49-96).
pub const FIELD_TYPE_ARRAY_OFFSET: u8 = 48;
/// Added to an element's id for a bounded sequence `T[<=N]` (97-144).
pub const FIELD_TYPE_BOUNDED_SEQUENCE_OFFSET: u8 = 96;
/// Added to an element's id for an unbounded sequence `T[]` (145-192).
pub const FIELD_TYPE_UNBOUNDED_SEQUENCE_OFFSET: u8 = 144;

/// The type of one field (`type_description_interfaces/msg/FieldType`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FieldType {
    /// One of the `FIELD_TYPE_*` ids (element id plus an array/sequence offset).
    pub type_id: u8,
    /// Array size or sequence bound; 0 otherwise.
    pub capacity: u64,
    /// Bound of a bounded or fixed string (or of the strings of an array/sequence); 0
    /// otherwise.
    pub string_capacity: u64,
    /// `pkg/msg/Name` of a nested type (or of the elements of an array/sequence of one); empty
    /// otherwise.
    pub nested_type_name: &'static str,
}

impl FieldType {
    /// A primitive or unbounded string field.
    pub const fn primitive(type_id: u8) -> Self {
        FieldType {
            type_id,
            capacity: 0,
            string_capacity: 0,
            nested_type_name: "",
        }
    }

    /// A field of another message type.
    pub const fn nested(type_name: &'static str) -> Self {
        FieldType {
            type_id: FIELD_TYPE_NESTED_TYPE,
            capacity: 0,
            string_capacity: 0,
            nested_type_name: type_name,
        }
    }

    /// An unbounded sequence `T[]` of a primitive (or unbounded string) `T`.
    pub const fn unbounded_sequence(element_type_id: u8) -> Self {
        FieldType {
            type_id: element_type_id + FIELD_TYPE_UNBOUNDED_SEQUENCE_OFFSET,
            capacity: 0,
            string_capacity: 0,
            nested_type_name: "",
        }
    }

    /// An unbounded sequence of another message type.
    pub const fn nested_unbounded_sequence(type_name: &'static str) -> Self {
        FieldType {
            type_id: FIELD_TYPE_NESTED_TYPE + FIELD_TYPE_UNBOUNDED_SEQUENCE_OFFSET,
            capacity: 0,
            string_capacity: 0,
            nested_type_name: type_name,
        }
    }

    /// A fixed-size array `T[N]` of a primitive `T`.
    pub const fn array(element_type_id: u8, len: u64) -> Self {
        FieldType {
            type_id: element_type_id + FIELD_TYPE_ARRAY_OFFSET,
            capacity: len,
            string_capacity: 0,
            nested_type_name: "",
        }
    }
}

/// One field of a type (`type_description_interfaces/msg/Field`, without `default_value`,
/// which the hash leaves out).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Field {
    /// Field name.
    pub name: &'static str,
    /// Its type.
    pub field_type: FieldType,
}

impl Field {
    /// A field.
    pub const fn new(name: &'static str, field_type: FieldType) -> Self {
        Field { name, field_type }
    }
}

/// One type without its references (`IndividualTypeDescription`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IndividualTypeDescription {
    /// `pkg/msg/Name`.
    pub type_name: &'static str,
    /// Fields in declaration order.
    pub fields: &'static [Field],
}

/// A type and everything it refers to (`TypeDescription`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TypeDescription {
    /// The type itself.
    pub type_description: &'static IndividualTypeDescription,
    /// Every type it refers to, directly or not, once each, sorted by name.
    pub referenced_type_descriptions: Vec<&'static IndividualTypeDescription>,
}

/// Why a type could not be described or a hash string parsed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TypeHashError {
    /// The type (or one it refers to) is not in [`DESCRIPTIONS`].
    #[error("no type description for {type_name}")]
    UnknownType {
        /// The missing type.
        type_name: String,
    },
    /// A string that is not `RIHS01_` followed by 64 lowercase hex digits.
    #[error("{text:?} is not an RIHS01 type hash")]
    NotRihs01 {
        /// The string.
        text: String,
    },
}

/// A RIHS01 type hash: SHA-256 of the canonical JSON. Displays as `RIHS01_<64 hex digits>`.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct TypeHash {
    /// The 32 bytes of the SHA-256 digest.
    pub sha256: [u8; 32],
}

impl TypeHash {
    /// The RIHS version this module implements.
    pub const VERSION: u8 = 1;

    /// Parses `RIHS01_<64 lowercase hex digits>`.
    pub fn parse(text: &str) -> Result<Self, TypeHashError> {
        let not = || TypeHashError::NotRihs01 {
            text: text.to_owned(),
        };
        let hex = text.strip_prefix("RIHS01_").ok_or_else(not)?;
        if hex.len() != 64 {
            return Err(not());
        }
        let mut sha256 = [0u8; 32];
        for (i, byte) in sha256.iter_mut().enumerate() {
            let hi = hex_digit(hex.as_bytes().get(2 * i).copied()).ok_or_else(not)?;
            let lo = hex_digit(hex.as_bytes().get(2 * i + 1).copied()).ok_or_else(not)?;
            *byte = (hi << 4) | lo;
        }
        Ok(TypeHash { sha256 })
    }
}

fn hex_digit(c: Option<u8>) -> Option<u8> {
    match c? {
        c @ b'0'..=b'9' => Some(c - b'0'),
        c @ b'a'..=b'f' => Some(c - b'a' + 10),
        _ => None,
    }
}

const HEX_DIGITS: &[u8; 16] = b"0123456789abcdef";

impl fmt::Display for TypeHash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "RIHS{:02x}_", Self::VERSION)?;
        for b in self.sha256 {
            write!(f, "{b:02x}")?;
        }
        Ok(())
    }
}

impl fmt::Debug for TypeHash {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "TypeHash({self})")
    }
}

// The descriptions, transcribed from the .msg files (common_interfaces, rcl_interfaces,
// crtk_msgs 1.3.0).

/// `builtin_interfaces/msg/Time`: `int32 sec`, `uint32 nanosec`.
pub const TIME: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "builtin_interfaces/msg/Time",
    fields: &[
        Field::new("sec", FieldType::primitive(FIELD_TYPE_INT32)),
        Field::new("nanosec", FieldType::primitive(FIELD_TYPE_UINT32)),
    ],
};

/// `std_msgs/msg/Header`: `builtin_interfaces/Time stamp`, `string frame_id`.
pub const HEADER: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "std_msgs/msg/Header",
    fields: &[
        Field::new("stamp", FieldType::nested("builtin_interfaces/msg/Time")),
        Field::new("frame_id", FieldType::primitive(FIELD_TYPE_STRING)),
    ],
};

/// `std_msgs/msg/String`: `string data`.
pub const STRING: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "std_msgs/msg/String",
    fields: &[Field::new("data", FieldType::primitive(FIELD_TYPE_STRING))],
};

/// `std_msgs/msg/MultiArrayDimension`: `string label`, `uint32 size`, `uint32 stride`.
pub const MULTI_ARRAY_DIMENSION: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "std_msgs/msg/MultiArrayDimension",
    fields: &[
        Field::new("label", FieldType::primitive(FIELD_TYPE_STRING)),
        Field::new("size", FieldType::primitive(FIELD_TYPE_UINT32)),
        Field::new("stride", FieldType::primitive(FIELD_TYPE_UINT32)),
    ],
};

/// `std_msgs/msg/MultiArrayLayout`: `MultiArrayDimension[] dim`, `uint32 data_offset`.
pub const MULTI_ARRAY_LAYOUT: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "std_msgs/msg/MultiArrayLayout",
    fields: &[
        Field::new(
            "dim",
            FieldType::nested_unbounded_sequence("std_msgs/msg/MultiArrayDimension"),
        ),
        Field::new("data_offset", FieldType::primitive(FIELD_TYPE_UINT32)),
    ],
};

/// `std_msgs/msg/Float64MultiArray`: `MultiArrayLayout layout`, `float64[] data`.
pub const FLOAT64_MULTI_ARRAY: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "std_msgs/msg/Float64MultiArray",
    fields: &[
        Field::new("layout", FieldType::nested("std_msgs/msg/MultiArrayLayout")),
        Field::new("data", FieldType::unbounded_sequence(FIELD_TYPE_DOUBLE)),
    ],
};

/// `geometry_msgs/msg/Point`: `float64 x, y, z`.
pub const POINT: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/Point",
    fields: &[
        Field::new("x", FieldType::primitive(FIELD_TYPE_DOUBLE)),
        Field::new("y", FieldType::primitive(FIELD_TYPE_DOUBLE)),
        Field::new("z", FieldType::primitive(FIELD_TYPE_DOUBLE)),
    ],
};

/// `geometry_msgs/msg/Quaternion`: `float64 x, y, z, w` (defaults 0, 0, 0, 1 are not hashed).
pub const QUATERNION: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/Quaternion",
    fields: &[
        Field::new("x", FieldType::primitive(FIELD_TYPE_DOUBLE)),
        Field::new("y", FieldType::primitive(FIELD_TYPE_DOUBLE)),
        Field::new("z", FieldType::primitive(FIELD_TYPE_DOUBLE)),
        Field::new("w", FieldType::primitive(FIELD_TYPE_DOUBLE)),
    ],
};

/// `geometry_msgs/msg/Pose`: `Point position`, `Quaternion orientation`.
pub const POSE: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/Pose",
    fields: &[
        Field::new("position", FieldType::nested("geometry_msgs/msg/Point")),
        Field::new(
            "orientation",
            FieldType::nested("geometry_msgs/msg/Quaternion"),
        ),
    ],
};

/// `geometry_msgs/msg/PoseStamped`: `std_msgs/Header header`, `Pose pose`.
pub const POSE_STAMPED: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/PoseStamped",
    fields: &[
        Field::new("header", FieldType::nested("std_msgs/msg/Header")),
        Field::new("pose", FieldType::nested("geometry_msgs/msg/Pose")),
    ],
};

/// `geometry_msgs/msg/Vector3`: `float64 x, y, z`.
pub const VECTOR3: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/Vector3",
    fields: &[
        Field::new("x", FieldType::primitive(FIELD_TYPE_DOUBLE)),
        Field::new("y", FieldType::primitive(FIELD_TYPE_DOUBLE)),
        Field::new("z", FieldType::primitive(FIELD_TYPE_DOUBLE)),
    ],
};

/// `geometry_msgs/msg/Twist`: `Vector3 linear`, `Vector3 angular`.
pub const TWIST: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/Twist",
    fields: &[
        Field::new("linear", FieldType::nested("geometry_msgs/msg/Vector3")),
        Field::new("angular", FieldType::nested("geometry_msgs/msg/Vector3")),
    ],
};

/// `geometry_msgs/msg/TwistStamped`: `std_msgs/Header header`, `Twist twist`.
pub const TWIST_STAMPED: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/TwistStamped",
    fields: &[
        Field::new("header", FieldType::nested("std_msgs/msg/Header")),
        Field::new("twist", FieldType::nested("geometry_msgs/msg/Twist")),
    ],
};

/// `geometry_msgs/msg/Wrench`: `Vector3 force`, `Vector3 torque`.
pub const WRENCH: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/Wrench",
    fields: &[
        Field::new("force", FieldType::nested("geometry_msgs/msg/Vector3")),
        Field::new("torque", FieldType::nested("geometry_msgs/msg/Vector3")),
    ],
};

/// `geometry_msgs/msg/WrenchStamped`: `std_msgs/Header header`, `Wrench wrench`.
pub const WRENCH_STAMPED: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "geometry_msgs/msg/WrenchStamped",
    fields: &[
        Field::new("header", FieldType::nested("std_msgs/msg/Header")),
        Field::new("wrench", FieldType::nested("geometry_msgs/msg/Wrench")),
    ],
};

/// `sensor_msgs/msg/Joy`: `std_msgs/Header header`, `float32[] axes`, `int32[] buttons`.
pub const JOY: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "sensor_msgs/msg/Joy",
    fields: &[
        Field::new("header", FieldType::nested("std_msgs/msg/Header")),
        Field::new("axes", FieldType::unbounded_sequence(FIELD_TYPE_FLOAT)),
        Field::new("buttons", FieldType::unbounded_sequence(FIELD_TYPE_INT32)),
    ],
};

/// `crtk_msgs/msg/OperatingState`: `std_msgs/Header header`, `string state`, `bool is_homed`,
/// `bool is_busy`.
pub const OPERATING_STATE: IndividualTypeDescription = IndividualTypeDescription {
    type_name: "crtk_msgs/msg/OperatingState",
    fields: &[
        Field::new("header", FieldType::nested("std_msgs/msg/Header")),
        Field::new("state", FieldType::primitive(FIELD_TYPE_STRING)),
        Field::new("is_homed", FieldType::primitive(FIELD_TYPE_BOOLEAN)),
        Field::new("is_busy", FieldType::primitive(FIELD_TYPE_BOOLEAN)),
    ],
};

/// Every type this module describes.
pub const DESCRIPTIONS: &[&IndividualTypeDescription] = &[
    &TIME,
    &HEADER,
    &STRING,
    &MULTI_ARRAY_DIMENSION,
    &MULTI_ARRAY_LAYOUT,
    &FLOAT64_MULTI_ARRAY,
    &POINT,
    &QUATERNION,
    &POSE,
    &POSE_STAMPED,
    &VECTOR3,
    &TWIST,
    &TWIST_STAMPED,
    &WRENCH,
    &WRENCH_STAMPED,
    &JOY,
    &OPERATING_STATE,
];

/// The individual description of `type_name` (`pkg/msg/Name`), if this module has it.
pub fn individual(type_name: &str) -> Option<&'static IndividualTypeDescription> {
    DESCRIPTIONS
        .iter()
        .copied()
        .find(|d| d.type_name == type_name)
}

/// The full description of `type_name`: the type and everything it refers to.
pub fn describe(type_name: &str) -> Result<TypeDescription, TypeHashError> {
    let unknown = |name: &str| TypeHashError::UnknownType {
        type_name: name.to_owned(),
    };
    let top = individual(type_name).ok_or_else(|| unknown(type_name))?;
    let mut referenced: BTreeMap<&'static str, &'static IndividualTypeDescription> =
        BTreeMap::new();
    let mut pending: Vec<&'static str> = nested_names(top).collect();
    while let Some(name) = pending.pop() {
        if name == top.type_name || referenced.contains_key(name) {
            continue;
        }
        let d = individual(name).ok_or_else(|| unknown(name))?;
        referenced.insert(name, d);
        pending.extend(nested_names(d));
    }
    Ok(TypeDescription {
        type_description: top,
        referenced_type_descriptions: referenced.into_values().collect(),
    })
}

fn nested_names(d: &'static IndividualTypeDescription) -> impl Iterator<Item = &'static str> {
    d.fields
        .iter()
        .map(|f| f.field_type.nested_type_name)
        .filter(|n| !n.is_empty())
}

/// The RIHS01 hash of `type_name`.
pub fn rihs01(type_name: &str) -> Result<TypeHash, TypeHashError> {
    Ok(describe(type_name)?.rihs01())
}

impl TypeDescription {
    /// The canonical JSON text the hash is taken over.
    pub fn canonical_json(&self) -> String {
        let mut out = String::with_capacity(2048);
        out.push_str("{\"type_description\": ");
        push_individual(&mut out, self.type_description);
        out.push_str(", \"referenced_type_descriptions\": [");
        for (i, d) in self.referenced_type_descriptions.iter().enumerate() {
            if i > 0 {
                out.push_str(", ");
            }
            push_individual(&mut out, d);
        }
        out.push_str("]}");
        out
    }

    /// The RIHS01 hash: SHA-256 of [`TypeDescription::canonical_json`].
    pub fn rihs01(&self) -> TypeHash {
        let digest = Sha256::digest(self.canonical_json().as_bytes());
        let mut sha256 = [0u8; 32];
        sha256.copy_from_slice(digest.as_slice());
        TypeHash { sha256 }
    }
}

fn push_individual(out: &mut String, d: &IndividualTypeDescription) {
    out.push_str("{\"type_name\": ");
    push_json_string(out, d.type_name);
    out.push_str(", \"fields\": [");
    for (i, f) in d.fields.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        out.push_str("{\"name\": ");
        push_json_string(out, f.name);
        out.push_str(", \"type\": {\"type_id\": ");
        out.push_str(&f.field_type.type_id.to_string());
        out.push_str(", \"capacity\": ");
        out.push_str(&f.field_type.capacity.to_string());
        out.push_str(", \"string_capacity\": ");
        out.push_str(&f.field_type.string_capacity.to_string());
        out.push_str(", \"nested_type_name\": ");
        push_json_string(out, f.field_type.nested_type_name);
        out.push_str("}}");
    }
    out.push_str("]}");
}

/// A JSON string as Python's `json.dumps(..., ensure_ascii=True)` writes it: `"` and `\`
/// escaped, `\n \r \t \b \f` by name, every other character outside space..`~` as `\uXXXX`
/// (lowercase hex, UTF-16 surrogate pairs above U+FFFF).
fn push_json_string(out: &mut String, s: &str) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            '\u{8}' => out.push_str("\\b"),
            '\u{c}' => out.push_str("\\f"),
            ' '..='~' => out.push(c),
            _ => {
                let mut units = [0u16; 2];
                for unit in c.encode_utf16(&mut units) {
                    out.push_str("\\u");
                    for shift in [12u16, 8, 4, 0] {
                        out.push(char::from(HEX_DIGITS[usize::from((*unit >> shift) & 0xf)]));
                    }
                }
            }
        }
    }
    out.push('"');
}

/// The line between the definitions of a `ros2msg` schema: 80 `=` (rosbag2's
/// `docs/message_definition_encoding.md`).
pub const ROS2MSG_DELIMITER: &str =
    "================================================================================";

/// The complete message definition of `type_name` in rosbag2's `ros2msg` encoding, as MCAP
/// schemas of ROS 2 channels carry it (schema encoding `ros2msg`): the type's `.msg` text
/// first, then each type it refers to (directly or not, once each, in name order) after a line
/// of [`ROS2MSG_DELIMITER`] and a line `MSG: pkg/msg/Name`. Rendered from the same
/// descriptions the RIHS01 hashes are computed from (fields only: the descriptions carry no
/// comments, constants or default values, which decoders do not need).
pub fn ros2msg_definition(type_name: &str) -> Result<String, TypeHashError> {
    let d = describe(type_name)?;
    let mut out = String::with_capacity(1024);
    push_msg_fields(&mut out, d.type_description)?;
    for r in &d.referenced_type_descriptions {
        out.push_str(ROS2MSG_DELIMITER);
        out.push_str("\nMSG: ");
        out.push_str(r.type_name);
        out.push('\n');
        push_msg_fields(&mut out, r)?;
    }
    Ok(out)
}

/// One `.msg` line per field: `<type> <name>`.
fn push_msg_fields(out: &mut String, d: &IndividualTypeDescription) -> Result<(), TypeHashError> {
    for f in d.fields {
        out.push_str(
            &msg_field_type(&f.field_type).ok_or_else(|| TypeHashError::UnknownType {
                type_name: format!("{} (field {}: no .msg form)", d.type_name, f.name),
            })?,
        );
        out.push(' ');
        out.push_str(f.name);
        out.push('\n');
    }
    Ok(())
}

/// A field's type as a `.msg` file writes it (`float64`, `std_msgs/Header`, `int32[]`,
/// `float64[36]`, `string<=8`); None for ids with no `.msg` form (`long double`, not set).
pub fn msg_field_type(t: &FieldType) -> Option<String> {
    let (element, suffix) = match t.type_id {
        id @ 1..=48 => (id, String::new()),
        id @ 49..=96 => (id - FIELD_TYPE_ARRAY_OFFSET, format!("[{}]", t.capacity)),
        id @ 97..=144 => (
            id - FIELD_TYPE_BOUNDED_SEQUENCE_OFFSET,
            format!("[<={}]", t.capacity),
        ),
        id @ 145..=192 => (id - FIELD_TYPE_UNBOUNDED_SEQUENCE_OFFSET, "[]".to_owned()),
        _ => return None,
    };
    let base = match element {
        FIELD_TYPE_NESTED_TYPE => {
            // `pkg/msg/Name` is written `pkg/Name` in a field.
            let mut parts = t.nested_type_name.split('/');
            match (parts.next(), parts.next(), parts.next(), parts.next()) {
                (Some(pkg), Some("msg"), Some(name), None) => format!("{pkg}/{name}"),
                _ => return None,
            }
        }
        FIELD_TYPE_BOUNDED_STRING => format!("string<={}", t.string_capacity),
        FIELD_TYPE_BOUNDED_WSTRING => format!("wstring<={}", t.string_capacity),
        id => msg_primitive_name(id)?.to_owned(),
    };
    Some(base + &suffix)
}

fn msg_primitive_name(id: u8) -> Option<&'static str> {
    Some(match id {
        FIELD_TYPE_INT8 => "int8",
        FIELD_TYPE_UINT8 => "uint8",
        FIELD_TYPE_INT16 => "int16",
        FIELD_TYPE_UINT16 => "uint16",
        FIELD_TYPE_INT32 => "int32",
        FIELD_TYPE_UINT32 => "uint32",
        FIELD_TYPE_INT64 => "int64",
        FIELD_TYPE_UINT64 => "uint64",
        FIELD_TYPE_FLOAT => "float32",
        FIELD_TYPE_DOUBLE => "float64",
        FIELD_TYPE_CHAR => "char",
        FIELD_TYPE_BOOLEAN => "bool",
        FIELD_TYPE_BYTE => "byte",
        FIELD_TYPE_STRING => "string",
        FIELD_TYPE_WSTRING => "wstring",
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn sequence_and_array_ids_match_field_type_msg() {
        // Spot checks against the table in FieldType.msg.
        assert_eq!(FieldType::unbounded_sequence(FIELD_TYPE_FLOAT).type_id, 154);
        assert_eq!(FieldType::unbounded_sequence(FIELD_TYPE_INT32).type_id, 150);
        assert_eq!(
            FieldType::unbounded_sequence(FIELD_TYPE_DOUBLE).type_id,
            155
        );
        assert_eq!(FieldType::nested_unbounded_sequence("a/msg/B").type_id, 145);
        assert_eq!(FieldType::array(FIELD_TYPE_DOUBLE, 36).type_id, 59);
        assert_eq!(
            FIELD_TYPE_NESTED_TYPE + FIELD_TYPE_BOUNDED_SEQUENCE_OFFSET,
            97
        );
        assert_eq!(
            FIELD_TYPE_BOUNDED_WSTRING + FIELD_TYPE_UNBOUNDED_SEQUENCE_OFFSET,
            166
        );
    }

    #[test]
    fn std_msgs_string_matches_rmw_zenoh_design_md() {
        // docs/design.md of ros2/rmw_zenoh: 0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...
        assert_eq!(
            rihs01("std_msgs/msg/String").unwrap().to_string(),
            "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        );
    }

    #[test]
    fn references_are_transitive_sorted_and_unique() {
        let d = describe("geometry_msgs/msg/PoseStamped").unwrap();
        let names: Vec<&str> = d
            .referenced_type_descriptions
            .iter()
            .map(|r| r.type_name)
            .collect();
        assert_eq!(
            names,
            [
                "builtin_interfaces/msg/Time",
                "geometry_msgs/msg/Point",
                "geometry_msgs/msg/Pose",
                "geometry_msgs/msg/Quaternion",
                "std_msgs/msg/Header",
            ]
        );
        // Twist refers to Vector3 twice; it is listed once.
        let t = describe("geometry_msgs/msg/Twist").unwrap();
        assert_eq!(t.referenced_type_descriptions.len(), 1);
    }

    #[test]
    fn canonical_json_of_a_leaf_type() {
        let d = describe("builtin_interfaces/msg/Time").unwrap();
        assert_eq!(
            d.canonical_json(),
            "{\"type_description\": {\"type_name\": \"builtin_interfaces/msg/Time\", \"fields\": \
             [{\"name\": \"sec\", \"type\": {\"type_id\": 6, \"capacity\": 0, \"string_capacity\": \
             0, \"nested_type_name\": \"\"}}, {\"name\": \"nanosec\", \"type\": {\"type_id\": 7, \
             \"capacity\": 0, \"string_capacity\": 0, \"nested_type_name\": \"\"}}]}, \
             \"referenced_type_descriptions\": []}"
        );
    }

    #[test]
    fn json_strings_escape_like_python_ensure_ascii() {
        let mut s = String::new();
        push_json_string(&mut s, "a\"b\\c\n\u{7f}é😀");
        assert_eq!(s, "\"a\\\"b\\\\c\\n\\u007f\\u00e9\\ud83d\\ude00\"");
    }

    #[test]
    fn unknown_types_are_errors() {
        assert_eq!(
            rihs01("nope/msg/Nope"),
            Err(TypeHashError::UnknownType {
                type_name: "nope/msg/Nope".into()
            })
        );
    }

    #[test]
    fn hash_strings_round_trip() {
        let h = rihs01("std_msgs/msg/Header").unwrap();
        assert_eq!(TypeHash::parse(&h.to_string()).unwrap(), h);
        assert!(TypeHash::parse("RIHS01_00").is_err());
        assert!(TypeHash::parse("TypeHashNotSupported").is_err());
        assert!(TypeHash::parse(&h.to_string().to_uppercase()).is_err());
    }

    #[test]
    fn ros2msg_definition_of_pose_stamped() {
        let text = ros2msg_definition("geometry_msgs/msg/PoseStamped").unwrap();
        let bar = "=".repeat(80);
        let expected = format!(
            "std_msgs/Header header\ngeometry_msgs/Pose pose\n\
             {bar}\nMSG: builtin_interfaces/msg/Time\nint32 sec\nuint32 nanosec\n\
             {bar}\nMSG: geometry_msgs/msg/Point\nfloat64 x\nfloat64 y\nfloat64 z\n\
             {bar}\nMSG: geometry_msgs/msg/Pose\n\
             geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n\
             {bar}\nMSG: geometry_msgs/msg/Quaternion\n\
             float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n\
             {bar}\nMSG: std_msgs/msg/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
        );
        assert_eq!(text, expected);
        assert_eq!(ROS2MSG_DELIMITER, bar);
    }

    /// Parses a `ros2msg` text back into (type name, [(field type, field name)]) per
    /// definition, the first one named `top`.
    fn parse_ros2msg(top: &str, text: &str) -> Vec<(String, Vec<(String, String)>)> {
        let mut defs = vec![(top.to_owned(), Vec::new())];
        let mut lines = text.lines();
        while let Some(line) = lines.next() {
            if line == ROS2MSG_DELIMITER {
                let name = lines.next().unwrap().strip_prefix("MSG: ").unwrap();
                defs.push((name.to_owned(), Vec::new()));
                continue;
            }
            let (ty, name) = line.split_once(' ').unwrap();
            defs.last_mut()
                .unwrap()
                .1
                .push((ty.to_owned(), name.to_owned()));
        }
        defs
    }

    /// Every type's schema text parses back into exactly its description and those of all
    /// it refers to (names, order, field types). Control: a changed description no longer
    /// matches the text.
    #[test]
    fn ros2msg_text_parses_back_into_the_type_descriptions() {
        for d in DESCRIPTIONS {
            let text = ros2msg_definition(d.type_name).unwrap();
            let defs = parse_ros2msg(d.type_name, &text);
            let full = describe(d.type_name).unwrap();
            let expected: Vec<&IndividualTypeDescription> = std::iter::once(full.type_description)
                .chain(full.referenced_type_descriptions.iter().copied())
                .collect();
            assert_eq!(defs.len(), expected.len(), "{}", d.type_name);
            for ((name, fields), e) in defs.iter().zip(&expected) {
                assert_eq!(name, e.type_name);
                let want: Vec<(String, String)> = e
                    .fields
                    .iter()
                    .map(|f| (msg_field_type(&f.field_type).unwrap(), f.name.to_owned()))
                    .collect();
                assert_eq!(fields, &want, "{name}");
            }
        }
        let joy = ros2msg_definition("sensor_msgs/msg/Joy").unwrap();
        assert!(joy.starts_with("std_msgs/Header header\nfloat32[] axes\nint32[] buttons\n"));
        let fma = ros2msg_definition("std_msgs/msg/Float64MultiArray").unwrap();
        assert!(
            fma.contains(
                "MSG: std_msgs/msg/MultiArrayLayout\nstd_msgs/MultiArrayDimension[] dim\n"
            )
        );
        // Control: the same parse of another type's text differs.
        let other = parse_ros2msg(
            "geometry_msgs/msg/TwistStamped",
            &ros2msg_definition("geometry_msgs/msg/WrenchStamped").unwrap(),
        );
        assert_ne!(
            other[0].1[1],
            ("geometry_msgs/Twist".to_owned(), "twist".to_owned())
        );
    }

    #[test]
    fn msg_field_types_of_arrays_and_bounds() {
        assert_eq!(
            msg_field_type(&FieldType::array(FIELD_TYPE_DOUBLE, 36)).as_deref(),
            Some("float64[36]")
        );
        let bounded = FieldType {
            type_id: FIELD_TYPE_BOUNDED_STRING + FIELD_TYPE_BOUNDED_SEQUENCE_OFFSET,
            capacity: 3,
            string_capacity: 8,
            nested_type_name: "",
        };
        assert_eq!(msg_field_type(&bounded).as_deref(), Some("string<=8[<=3]"));
        assert_eq!(
            msg_field_type(&FieldType::primitive(FIELD_TYPE_LONG_DOUBLE)),
            None
        );
        assert_eq!(msg_field_type(&FieldType::nested("no_msg_part")), None);
    }
}
