//! What a ROS 2 subscription does with each publication it receives, before anything reaches
//! the 1 kHz loop (issue 35, subscriptions). Pure: no Zenoh session here (`node` declares the
//! Zenoh subscriber and calls [`Intake::take`] from its callback).
//!
//! A subscription listens on `<domain>/<topic>/*/*` (every type on the topic), so that a
//! publication of the wrong type is seen and counted instead of silently missed. Each sample
//! is then checked, in this order, and the first failure is its reason ([`RejectReason`]):
//!
//! 1. the key's type chunks (`<dds type name>/<type hash>`) must be this subscription's
//!    (`wrong_type`);
//! 2. the attachment must be rmw_zenoh's 33 bytes (`bad_attachment`);
//! 3. one publisher owns the topic: the first GID seen; a sample from another GID is a second
//!    device on the same topic (`second_publisher`). The owner is released after it has been
//!    silent for the owner timeout, so a restarted device (a new GID) takes over;
//! 4. the payload must decode as the type: a payload that ends early is `truncated`, any
//!    other CDR error (bad header, trailing bytes, a bad boolean or string) `wrong_type`;
//! 5. every float must be finite (`non_finite`: NaN poses).
//!
//! Rejected samples are counted by reason ([`RejectCounters`], atomics the summary reads at
//! the end) and never acted on. Accepted ones are converted (to project units) and written
//! into a [`super::telemetry::LatestCell`], which the 1 kHz loop reads with
//! [`super::telemetry::LatestCell::try_newer_than`]: no waiting, no allocation on the loop's
//! side. Decoding (which may allocate, e.g. `sensor_msgs/Joy`'s sequences) happens on the
//! subscriber's thread.

use std::sync::atomic::{AtomicU64, Ordering};

use serde::{Deserialize, Serialize};

use super::cdr::CdrError;
use super::keys::{Attachment, Distro, GID_LEN, KeyError, TypeHashField, dds_type_name};
use super::msgs::{DecodeError, Ros2Message};

/// Why a received sample was not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RejectReason {
    /// The payload ends inside a value (or has no encapsulation header).
    Truncated,
    /// The key's type name or hash is not the subscription's, or the payload does not decode
    /// as the type.
    WrongType,
    /// A value (a pose's coordinate, a wrench's component) is NaN or infinite.
    NonFinite,
    /// Another publisher (a different GID in the attachment) than the one that owns the topic.
    SecondPublisher,
    /// No attachment, or not rmw_zenoh's 33 bytes.
    BadAttachment,
}

/// Rejected samples by reason, as the summaries show them (`ros2_rejected`).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(default)]
pub struct Ros2Rejected {
    /// Payloads that end inside a value (or have no CDR header).
    pub truncated: u64,
    /// Publications of another type on the topic (type name or hash in the key), or payloads
    /// that do not decode as the topic's type.
    pub wrong_type: u64,
    /// Messages with a NaN or infinite value.
    pub non_finite: u64,
    /// Messages from a second publisher (another GID) on a topic a device already owns.
    pub second_publisher: u64,
    /// Messages without rmw_zenoh's 33-byte attachment.
    pub bad_attachment: u64,
}

impl Ros2Rejected {
    /// All rejected samples.
    pub fn total(&self) -> u64 {
        self.truncated
            + self.wrong_type
            + self.non_finite
            + self.second_publisher
            + self.bad_attachment
    }

    /// The sum of two counts, reason by reason.
    pub fn plus(&self, o: &Ros2Rejected) -> Ros2Rejected {
        Ros2Rejected {
            truncated: self.truncated + o.truncated,
            wrong_type: self.wrong_type + o.wrong_type,
            non_finite: self.non_finite + o.non_finite,
            second_publisher: self.second_publisher + o.second_publisher,
            bad_attachment: self.bad_attachment + o.bad_attachment,
        }
    }
}

/// Accepted and rejected samples of a subscription, shared between its callback (which
/// counts) and whoever reports them.
#[derive(Debug, Default)]
pub struct RejectCounters {
    accepted: AtomicU64,
    truncated: AtomicU64,
    wrong_type: AtomicU64,
    non_finite: AtomicU64,
    second_publisher: AtomicU64,
    bad_attachment: AtomicU64,
}

impl RejectCounters {
    /// Counts one rejected sample.
    pub fn reject(&self, reason: RejectReason) {
        let c = match reason {
            RejectReason::Truncated => &self.truncated,
            RejectReason::WrongType => &self.wrong_type,
            RejectReason::NonFinite => &self.non_finite,
            RejectReason::SecondPublisher => &self.second_publisher,
            RejectReason::BadAttachment => &self.bad_attachment,
        };
        c.fetch_add(1, Ordering::Relaxed);
    }

    /// Counts one accepted sample.
    pub fn accept(&self) {
        self.accepted.fetch_add(1, Ordering::Relaxed);
    }

    /// Samples accepted so far.
    pub fn accepted(&self) -> u64 {
        self.accepted.load(Ordering::Relaxed)
    }

    /// Rejected samples so far, by reason.
    pub fn rejected(&self) -> Ros2Rejected {
        let l = |c: &AtomicU64| c.load(Ordering::Relaxed);
        Ros2Rejected {
            truncated: l(&self.truncated),
            wrong_type: l(&self.wrong_type),
            non_finite: l(&self.non_finite),
            second_publisher: l(&self.second_publisher),
            bad_attachment: l(&self.bad_attachment),
        }
    }
}

/// The checks of one subscription of message type `M`: the key's expected type chunks and
/// the publisher that owns the topic.
#[derive(Clone, Debug)]
pub struct Intake {
    /// `<dds type name>/<type hash>`, the end of every key this subscription takes.
    type_suffix: String,
    owner: Option<Owner>,
    owner_timeout_ns: u64,
}

#[derive(Clone, Copy, Debug)]
struct Owner {
    gid: [u8; GID_LEN],
    last_ns: u64,
}

impl Intake {
    /// The checks for `type_name` (`pkg/msg/Name`) in `distro`'s key format; the topic's
    /// owner is released after `owner_timeout_ns` of silence.
    pub fn new(type_name: &str, distro: Distro, owner_timeout_ns: u64) -> Result<Self, KeyError> {
        let hash = TypeHashField::for_type(distro, type_name)?;
        Ok(Intake {
            type_suffix: format!("{}/{hash}", dds_type_name(type_name)?),
            owner: None,
            owner_timeout_ns,
        })
    }

    /// The key's expected end, `<dds type name>/<type hash>`.
    pub fn type_suffix(&self) -> &str {
        &self.type_suffix
    }

    /// The GID of the publisher that owns the topic now, if any.
    pub fn owner(&self) -> Option<[u8; GID_LEN]> {
        self.owner.map(|o| o.gid)
    }

    /// Checks one sample received at `now_ns` (any monotonic clock) on `key` with `payload`
    /// and `attachment`, and decodes it as `M`: the message, or why it is refused (the module
    /// doc gives the order of the checks). Counts nothing ([`Intake::take`] does).
    pub fn check<M: Ros2Message>(
        &mut self,
        key: &str,
        payload: &[u8],
        attachment: Option<&[u8]>,
        now_ns: u64,
    ) -> Result<M, RejectReason> {
        let type_ok = key
            .strip_suffix(self.type_suffix.as_str())
            .is_some_and(|head| head.ends_with('/'));
        if !type_ok {
            return Err(RejectReason::WrongType);
        }
        let att = attachment
            .ok_or(RejectReason::BadAttachment)
            .and_then(|a| Attachment::from_bytes(a).map_err(|_| RejectReason::BadAttachment))?;
        match self.owner {
            Some(o)
                if o.gid != att.gid
                    && now_ns.saturating_sub(o.last_ns) <= self.owner_timeout_ns =>
            {
                return Err(RejectReason::SecondPublisher);
            }
            _ => {}
        }
        let msg = M::decode_finite(payload).map_err(|e| match e {
            DecodeError::Cdr(CdrError::Truncated { .. } | CdrError::MissingHeader { .. }) => {
                RejectReason::Truncated
            }
            DecodeError::Cdr(_) => RejectReason::WrongType,
            DecodeError::NonFinite(_) => RejectReason::NonFinite,
        })?;
        // Only a well-formed message from the owner (or a new one) keeps the topic owned.
        self.owner = Some(Owner {
            gid: att.gid,
            last_ns: now_ns,
        });
        Ok(msg)
    }

    /// [`Intake::check`], counting the sample as accepted or by its reason in `counters`.
    pub fn take<M: Ros2Message>(
        &mut self,
        counters: &RejectCounters,
        key: &str,
        payload: &[u8],
        attachment: Option<&[u8]>,
        now_ns: u64,
    ) -> Option<M> {
        match self.check::<M>(key, payload, attachment, now_ns) {
            Ok(m) => {
                counters.accept();
                Some(m)
            }
            Err(r) => {
                counters.reject(r);
                None
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::ros2::keys::{Qos, TopicInfo};
    use crate::ros2::msgs::{Header, Pose, PoseStamped, TwistStamped};
    use crate::ros2::units;

    const MS: u64 = 1_000_000;

    fn key_of(type_name: &str) -> String {
        TopicInfo::new(
            "/dev/measured_cp",
            type_name,
            Distro::Jazzy,
            Qos::keep_last(1),
        )
        .unwrap()
        .key_expr(0)
    }

    fn pose_bytes(x_m: f64) -> Vec<u8> {
        PoseStamped {
            header: Header::default(),
            pose: Pose {
                position: crate::ros2::msgs::Point {
                    x: x_m,
                    y: 0.0,
                    z: 0.0,
                },
                orientation: units::quaternion_about_y(0.0),
            },
        }
        .encode()
        .unwrap()
    }

    fn att(gid_byte: u8, seq: i64) -> [u8; 33] {
        Attachment {
            sequence_number: seq,
            source_timestamp_ns: 0,
            gid: [gid_byte; GID_LEN],
        }
        .to_bytes()
    }

    fn intake() -> Intake {
        Intake::new(PoseStamped::TYPE_NAME, Distro::Jazzy, 20 * MS).unwrap()
    }

    /// A good pose is accepted; then each kind of bad input is refused for its own reason
    /// and counted, and the good one before and after shows nothing else was disturbed.
    #[test]
    fn each_bad_input_is_refused_for_its_reason() {
        let mut i = intake();
        let c = RejectCounters::default();
        let key = key_of(PoseStamped::TYPE_NAME);
        let good = pose_bytes(0.01);
        let a = att(1, 1);
        let m: PoseStamped = i.take(&c, &key, &good, Some(&a), MS).unwrap();
        assert_eq!(m.pose.position.x, 0.01);
        // Truncated: every strict prefix of a good payload.
        for n in 0..good.len() - 1 {
            assert_eq!(
                i.check::<PoseStamped>(&key, &good[..n], Some(&a), 2 * MS)
                    .unwrap_err(),
                RejectReason::Truncated,
                "prefix of {n} bytes"
            );
        }
        // Wrong type: on the key (TwistStamped's name and hash) ...
        let twist_key = key_of(TwistStamped::TYPE_NAME);
        assert!(
            i.take::<PoseStamped>(&c, &twist_key, &good, Some(&a), 2 * MS)
                .is_none()
        );
        // ... the right name with another hash, and a payload that is not a PoseStamped
        // (a bad encapsulation header).
        let bad_hash = key.replace("RIHS01_1", "RIHS01_2");
        assert!(
            i.take::<PoseStamped>(&c, &bad_hash, &good, Some(&a), 2 * MS)
                .is_none()
        );
        let mut big_endian = good.clone();
        big_endian[1] = 0x00;
        assert!(
            i.take::<PoseStamped>(&c, &key, &big_endian, Some(&a), 2 * MS)
                .is_none()
        );
        // NaN pose.
        let nan = pose_bytes(f64::NAN);
        assert!(
            i.take::<PoseStamped>(&c, &key, &nan, Some(&a), 3 * MS)
                .is_none()
        );
        // A second publisher while the first is alive.
        assert!(
            i.take::<PoseStamped>(&c, &key, &good, Some(&att(2, 1)), 4 * MS)
                .is_none()
        );
        // No attachment, a short one.
        assert!(
            i.take::<PoseStamped>(&c, &key, &good, None, 4 * MS)
                .is_none()
        );
        assert!(
            i.take::<PoseStamped>(&c, &key, &good, Some(&a[..20]), 4 * MS)
                .is_none()
        );
        // A truncated sample counted once.
        assert!(
            i.take::<PoseStamped>(&c, &key, &good[..30], Some(&a), 4 * MS)
                .is_none()
        );
        // The owner still gets through.
        assert!(
            i.take::<PoseStamped>(&c, &key, &good, Some(&att(1, 2)), 5 * MS)
                .is_some()
        );
        assert_eq!(
            c.rejected(),
            Ros2Rejected {
                truncated: 1,
                wrong_type: 3,
                non_finite: 1,
                second_publisher: 1,
                bad_attachment: 2,
            }
        );
        assert_eq!(c.rejected().total(), 8);
        assert_eq!(c.accepted(), 2);
    }

    /// The owner is the first publisher; another GID is refused while the owner speaks and
    /// takes over once the owner has been silent longer than the timeout. Control: the same
    /// second GID within the timeout is refused.
    #[test]
    fn a_silent_owner_is_replaced_after_the_timeout() {
        let mut i = intake();
        let key = key_of(PoseStamped::TYPE_NAME);
        let good = pose_bytes(0.0);
        assert!(
            i.check::<PoseStamped>(&key, &good, Some(&att(1, 1)), MS)
                .is_ok()
        );
        assert_eq!(
            i.check::<PoseStamped>(&key, &good, Some(&att(2, 1)), 21 * MS)
                .unwrap_err(),
            RejectReason::SecondPublisher
        );
        assert!(
            i.check::<PoseStamped>(&key, &good, Some(&att(2, 2)), 22 * MS)
                .is_ok()
        );
        assert_eq!(i.owner(), Some([2; GID_LEN]));
        assert_eq!(
            i.check::<PoseStamped>(&key, &good, Some(&att(1, 3)), 23 * MS)
                .unwrap_err(),
            RejectReason::SecondPublisher
        );
    }

    /// A rejected sample from a stranger does not take or refresh the ownership: the owner
    /// times out on its own silence only.
    #[test]
    fn only_accepted_samples_own_the_topic() {
        let mut i = intake();
        let key = key_of(PoseStamped::TYPE_NAME);
        let nan = pose_bytes(f64::NAN);
        assert!(
            i.check::<PoseStamped>(&key, &nan, Some(&att(3, 1)), MS)
                .is_err()
        );
        assert_eq!(i.owner(), None);
    }

    #[test]
    fn humble_keys_carry_no_hash() {
        let i = Intake::new(PoseStamped::TYPE_NAME, Distro::Humble, MS).unwrap();
        assert_eq!(
            i.type_suffix(),
            "geometry_msgs::msg::dds_::PoseStamped_/TypeHashNotSupported"
        );
    }
}
