//! rmw_zenoh key expressions, liveliness tokens and attachments against the examples of
//! ros2/rmw_zenoh's `docs/design.md` (copied verbatim below), and the h4 topics' keys.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_transport::ros2::keys::{
    Attachment, Distro, EntityKind, NodeInfo, Qos, TopicInfo, TypeHashField, dds_type_name,
};
use h4_transport::ros2::msgs::{PoseStamped, Ros2Message};
use h4_transport::ros2::type_hash::TypeHash;
use h4_transport::ros2::{CrtkTopic, Ros2Names};

const STRING_HASH: &str = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18";
const ADD_TWO_INTS_HASH: &str =
    "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a";

fn chatter(depth: u64) -> TopicInfo {
    TopicInfo::new(
        "/chatter",
        "std_msgs/msg/String",
        Distro::Jazzy,
        Qos::keep_last(depth),
    )
    .unwrap()
}

/// The service examples' topic: AddTwoInts is not described here, so its hash is taken from
/// the document.
fn add_two_ints() -> TopicInfo {
    TopicInfo {
        fq_name: "/add_two_ints".into(),
        type_name: "example_interfaces/srv/AddTwoInts".into(),
        dds_type_name: dds_type_name("example_interfaces/srv/AddTwoInts").unwrap(),
        type_hash: TypeHashField::Rihs01(TypeHash::parse(ADD_TWO_INTS_HASH).unwrap()),
        qos: Qos::keep_last(10),
    }
}

#[test]
fn topic_keys_of_design_md() {
    assert_eq!(
        chatter(7).key_expr(0),
        format!("0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    );
    let namespaced = TopicInfo::new(
        "/robot1/chatter",
        "std_msgs/msg/String",
        Distro::Jazzy,
        Qos::default(),
    )
    .unwrap();
    assert_eq!(
        namespaced.key_expr(0),
        format!("0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
    );
    assert_eq!(
        add_two_ints().key_expr(2),
        format!("2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS_HASH}")
    );
}

#[test]
fn liveliness_tokens_of_design_md() {
    // design.md's examples use domain 2 (though the first one says "ROS_DOMAIN_ID=0 by
    // default"); node id 0, endpoint id 10, default enclave and namespace.
    let listener =
        NodeInfo::new(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener").unwrap();
    assert_eq!(
        listener.node_token(),
        "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    );
    assert_eq!(
        listener.endpoint_token(10, EntityKind::Subscription, &chatter(10)),
        format!(
            "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/\
             std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,"
        )
    );

    let talker = NodeInfo::new(2, "8b20917502ee955ac4476e0266340d5c", 0, "", "talker").unwrap();
    assert_eq!(
        talker.endpoint_token(10, EntityKind::Publisher, &chatter(7)),
        format!(
            "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/\
             std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,"
        )
    );

    let server = NodeInfo::new(
        2,
        "f9980ee0495eaafb3e38f0d19e2eae12",
        0,
        "/",
        "add_two_ints_server",
    )
    .unwrap();
    assert_eq!(
        server.endpoint_token(10, EntityKind::ServiceServer, &add_two_ints()),
        format!(
            "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/\
             %add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS_HASH}/\
             ::,10:,:,:,,"
        )
    );

    let client = NodeInfo::new(
        2,
        "e1dc8d1b45ae8717fce78689cc655685",
        0,
        "/",
        "add_two_ints_client",
    )
    .unwrap();
    assert_eq!(
        client.endpoint_token(10, EntityKind::ServiceClient, &add_two_ints()),
        format!(
            "@ros2_lv/2/e1dc8d1b45ae8717fce78689cc655685/0/10/SC/%/%/add_two_ints_client/\
             %add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS_HASH}/\
             ::,10:,:,:,,"
        )
    );
}

#[test]
fn the_slave_measured_cp_keys_jazzy_and_humble() {
    let names = Ros2Names::slave_default();
    let topic = names.topic(CrtkTopic::MeasuredCp);
    let type_name = CrtkTopic::MeasuredCp.type_name();
    assert_eq!(type_name, PoseStamped::TYPE_NAME);
    assert_eq!(
        PoseStamped::dds_type_name().unwrap(),
        "geometry_msgs::msg::dds_::PoseStamped_"
    );

    let jazzy = TopicInfo::new(&topic, type_name, Distro::Jazzy, Qos::keep_last(1)).unwrap();
    // The hash is rosbags' (tests/data/ros2_vectors.json).
    assert_eq!(
        jazzy.key_expr(0),
        "0/h4/measured_cp/geometry_msgs::msg::dds_::PoseStamped_/\
         RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8"
    );
    let humble = TopicInfo::new(&topic, type_name, Distro::Humble, Qos::keep_last(1)).unwrap();
    assert_eq!(
        humble.key_expr(0),
        "0/h4/measured_cp/geometry_msgs::msg::dds_::PoseStamped_/TypeHashNotSupported"
    );

    let node = NodeInfo::new(0, "1f2e3d4c", 0, names.namespace(), "h4_slave").unwrap();
    assert_eq!(
        node.node_token(),
        "@ros2_lv/0/1f2e3d4c/0/0/NN/%/%h4/h4_slave"
    );
    assert_eq!(
        node.endpoint_token(1, EntityKind::Publisher, &humble),
        "@ros2_lv/0/1f2e3d4c/0/1/MP/%/%h4/h4_slave/%h4%measured_cp/\
         geometry_msgs::msg::dds_::PoseStamped_/TypeHashNotSupported/::,1:,:,:,,"
    );
}

#[test]
fn every_crtk_topic_has_keys_on_both_distros() {
    for (names, topics) in [
        (Ros2Names::slave_default(), &CrtkTopic::SLAVE[..]),
        (Ros2Names::master_default(), &CrtkTopic::MASTER[..]),
    ] {
        for &t in topics {
            for distro in [Distro::Jazzy, Distro::Humble] {
                let info =
                    TopicInfo::new(&names.topic(t), t.type_name(), distro, Qos::default()).unwrap();
                let key = info.key_expr(0);
                assert!(
                    key.starts_with(&format!("0{}/", names.namespace())),
                    "{key}"
                );
                assert!(!key.contains("//"), "{key}");
            }
        }
    }
}

#[test]
fn bad_names_are_refused() {
    assert!(
        TopicInfo::new(
            "chatter",
            "std_msgs/msg/String",
            Distro::Jazzy,
            Qos::default()
        )
        .is_err()
    );
    assert!(TopicInfo::new("/chatter", "std_msgs/String", Distro::Jazzy, Qos::default()).is_err());
    // Not described here: no hash to put in a Jazzy key, but Humble needs none.
    assert!(TopicInfo::new("/x", "nav_msgs/msg/Odometry", Distro::Jazzy, Qos::default()).is_err());
    assert!(
        TopicInfo::new(
            "/x",
            "nav_msgs/msg/Odometry",
            Distro::Humble,
            Qos::default()
        )
        .is_ok()
    );
    assert!(NodeInfo::new(0, "AAC3", 0, "/", "n").is_err());
    assert!(NodeInfo::new(0, "aac3", 0, "h4", "n").is_err());
    assert!(NodeInfo::new(0, "aac3", 0, "/", "my-node").is_err());
}

#[test]
fn attachment_is_33_bytes_as_design_md_describes() {
    let a = Attachment {
        sequence_number: 42,
        source_timestamp_ns: 1_700_000_000_123_456_789,
        gid: *b"0123456789abcdef",
    };
    let bytes = a.to_bytes();
    assert_eq!(bytes.len(), 33);
    assert_eq!(&bytes[0..8], &42i64.to_le_bytes());
    assert_eq!(&bytes[8..16], &1_700_000_000_123_456_789i64.to_le_bytes());
    assert_eq!(bytes[16], 16);
    assert_eq!(&bytes[17..], b"0123456789abcdef");
    assert_eq!(Attachment::from_bytes(&bytes).unwrap(), a);
}
