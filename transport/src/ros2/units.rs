//! The one place where the project's units meet ROS's.
//!
//! Inside h4-teleop: mm, rad, N, N·mm; a pose is `[x_mm, y_mm, z_mm, theta_rad]` with θ about
//! y, a velocity `[mm/s, mm/s, mm/s, rad/s about y]`, a wrench `[Fx_n, Fy_n, Fz_n, My_n_mm]`.
//! On ROS topics (REP 103): m, rad, N, N·m, orientation as a unit quaternion. The axes are not
//! remapped: the H-4 frames are right-handed, as REP 103 asks, and keep their x, y, z.
//! Components the H-4's four degrees of freedom do not have (rotation about x and z, torque
//! about x and z) are published as 0 and ignored when read.

use std::f64::consts::{PI, TAU};

use super::msgs::{Point, Pose, Quaternion, Twist, Vector3, Wrench};

/// mm → m.
pub fn mm_to_m(length_mm: f64) -> f64 {
    length_mm / 1000.0
}

/// m → mm.
pub fn m_to_mm(length_m: f64) -> f64 {
    length_m * 1000.0
}

/// N·mm → N·m.
pub fn nmm_to_nm(torque_n_mm: f64) -> f64 {
    torque_n_mm / 1000.0
}

/// N·m → N·mm.
pub fn nm_to_nmm(torque_n_m: f64) -> f64 {
    torque_n_m * 1000.0
}

/// The unit quaternion of a rotation by `theta_rad` about y: (0, sin θ/2, 0, cos θ/2).
pub fn quaternion_about_y(theta_rad: f64) -> Quaternion {
    let half = 0.5 * theta_rad;
    Quaternion {
        x: 0.0,
        y: half.sin(),
        z: 0.0,
        w: half.cos(),
    }
}

/// The rotation about y of `q`, in (−π, π]: `2 atan2(y, w)`, exact for a rotation about y
/// (either sign of `q`, any norm); for any other rotation, the about-y part of it (x and z
/// are ignored).
pub fn theta_about_y_rad(q: &Quaternion) -> f64 {
    let theta = 2.0 * q.y.atan2(q.w);
    if theta > PI {
        theta - TAU
    } else if theta <= -PI {
        theta + TAU
    } else {
        theta
    }
}

/// An H-4 pose `[x_mm, y_mm, z_mm, theta_rad]` as a ROS pose (m, quaternion).
pub fn pose_to_ros(pose_mm_rad: &[f64; 4]) -> Pose {
    Pose {
        position: Point {
            x: mm_to_m(pose_mm_rad[0]),
            y: mm_to_m(pose_mm_rad[1]),
            z: mm_to_m(pose_mm_rad[2]),
        },
        orientation: quaternion_about_y(pose_mm_rad[3]),
    }
}

/// A ROS pose as an H-4 pose `[x_mm, y_mm, z_mm, theta_rad]` (θ from
/// [`theta_about_y_rad`]).
pub fn pose_from_ros(pose: &Pose) -> [f64; 4] {
    [
        m_to_mm(pose.position.x),
        m_to_mm(pose.position.y),
        m_to_mm(pose.position.z),
        theta_about_y_rad(&pose.orientation),
    ]
}

/// An H-4 velocity `[mm/s, mm/s, mm/s, rad/s about y]` as a ROS twist (m/s, rad/s).
pub fn velocity_to_ros(velocity_mm_s_rad_s: &[f64; 4]) -> Twist {
    Twist {
        linear: Vector3 {
            x: mm_to_m(velocity_mm_s_rad_s[0]),
            y: mm_to_m(velocity_mm_s_rad_s[1]),
            z: mm_to_m(velocity_mm_s_rad_s[2]),
        },
        angular: Vector3 {
            x: 0.0,
            y: velocity_mm_s_rad_s[3],
            z: 0.0,
        },
    }
}

/// A ROS twist as an H-4 velocity `[mm/s, mm/s, mm/s, rad/s about y]`.
pub fn velocity_from_ros(twist: &Twist) -> [f64; 4] {
    [
        m_to_mm(twist.linear.x),
        m_to_mm(twist.linear.y),
        m_to_mm(twist.linear.z),
        twist.angular.y,
    ]
}

/// An H-4 wrench `[Fx_n, Fy_n, Fz_n, My_n_mm]` as a ROS wrench (N, N·m).
pub fn wrench_to_ros(wrench_n_nmm: &[f64; 4]) -> Wrench {
    Wrench {
        force: Vector3 {
            x: wrench_n_nmm[0],
            y: wrench_n_nmm[1],
            z: wrench_n_nmm[2],
        },
        torque: Vector3 {
            x: 0.0,
            y: nmm_to_nm(wrench_n_nmm[3]),
            z: 0.0,
        },
    }
}

/// A ROS wrench as an H-4 wrench `[Fx_n, Fy_n, Fz_n, My_n_mm]`.
pub fn wrench_from_ros(wrench: &Wrench) -> [f64; 4] {
    [
        wrench.force.x,
        wrench.force.y,
        wrench.force.z,
        nm_to_nmm(wrench.torque.y),
    ]
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()))
    }

    #[test]
    fn lengths_and_torques() {
        assert_eq!(mm_to_m(1500.0), 1.5);
        assert_eq!(m_to_mm(0.25), 250.0);
        assert_eq!(nmm_to_nm(2500.0), 2.5);
        assert_eq!(nm_to_nmm(0.125), 125.0);
    }

    #[test]
    fn theta_about_y_is_a_quaternion_about_y() {
        let q = quaternion_about_y(std::f64::consts::FRAC_PI_2);
        assert_eq!((q.x, q.z), (0.0, 0.0));
        assert!(close(q.y, std::f64::consts::FRAC_1_SQRT_2));
        assert!(close(q.w, std::f64::consts::FRAC_1_SQRT_2));
        for theta in [-3.0, -1.0, -0.1, 0.0, 0.3, 1.4, 3.1] {
            let q = quaternion_about_y(theta);
            assert!(close(theta_about_y_rad(&q), theta), "{theta}");
            let neg = Quaternion {
                x: -q.x,
                y: -q.y,
                z: -q.z,
                w: -q.w,
            };
            assert!(close(theta_about_y_rad(&neg), theta), "-q, {theta}");
        }
    }

    #[test]
    fn the_rotation_about_y_is_right_handed() {
        // Right-handed rotation about +y takes +x towards −z: R·x = (cos θ, 0, −sin θ).
        let theta: f64 = 0.4;
        let q = quaternion_about_y(theta);
        // Rotated x axis, first column of the rotation matrix of q.
        let rx = 1.0 - 2.0 * (q.y * q.y + q.z * q.z);
        let rz = 2.0 * (q.x * q.z - q.w * q.y);
        assert!(close(rx, theta.cos()));
        assert!(close(rz, -theta.sin()));
    }

    #[test]
    fn poses_velocities_and_wrenches_round_trip() {
        let pose = [12.5, -3.0, 250.0, 0.2];
        let ros = pose_to_ros(&pose);
        assert!(close(ros.position.z, 0.25));
        let back = pose_from_ros(&ros);
        for (i, (got, want)) in back.iter().zip(pose.iter()).enumerate() {
            assert!(close(*got, *want), "pose {i}");
        }
        let v = [10.0, 0.0, -5.0, 0.5];
        let t = velocity_to_ros(&v);
        assert!(close(t.linear.x, 0.01));
        assert_eq!(t.angular.y, 0.5);
        let back = velocity_from_ros(&t);
        for (i, (got, want)) in back.iter().zip(v.iter()).enumerate() {
            assert!(close(*got, *want), "velocity {i}");
        }
        let w = [1.0, -2.0, 3.0, 400.0];
        let r = wrench_to_ros(&w);
        assert_eq!(r.torque.y, 0.4);
        assert_eq!((r.torque.x, r.torque.z), (0.0, 0.0));
        assert!(close(wrench_from_ros(&r)[3], 400.0));
    }
}
