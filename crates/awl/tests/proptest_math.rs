//! Property tests for the frame maths: inverses, composition, and the 4x4 rows boundary.

use awl::transform::{isometry_from_rows, isometry_from_translation_rotvec, pose_difference, rows_from_isometry};
use nalgebra::{Isometry3, Point3, Vector3};
use proptest::prelude::*;

fn pose() -> impl Strategy<Value = Isometry3<f64>> {
    (prop::array::uniform3(-5.0f64..5.0), prop::array::uniform3(-3.0f64..3.0))
        .prop_map(|(t, r)| isometry_from_translation_rotvec(Vector3::from(t), Vector3::from(r)))
}

proptest! {
    #[test]
    fn a_from_b_times_b_from_a_is_identity(a_from_b in pose()) {
        let b_from_a = a_from_b.inverse();
        let (dt, dr) = pose_difference(&(a_from_b * b_from_a), &Isometry3::identity());
        prop_assert!(dt < 1e-12 && dr < 1e-7, "dt {dt} dr {dr}");
    }

    #[test]
    fn composition_maps_points_like_the_chain(world_from_base in pose(), base_from_ee in pose(), ee_from_camera in pose(),
                                              p in prop::array::uniform3(-2.0f64..2.0)) {
        let p_camera = Point3::from(p);
        let world_from_camera = world_from_base * base_from_ee * ee_from_camera;
        let chained = world_from_base * (base_from_ee * (ee_from_camera * p_camera));
        prop_assert!((world_from_camera * p_camera - chained).norm() < 1e-10);
        let back = world_from_camera.inverse() * chained;
        prop_assert!((back - p_camera).norm() < 1e-10);
    }

    #[test]
    fn rows_round_trip(a_from_b in pose()) {
        let parsed = isometry_from_rows(&rows_from_isometry(&a_from_b)).expect("rigid");
        let (dt, dr) = pose_difference(&parsed, &a_from_b);
        prop_assert!(dt < 1e-12 && dr < 1e-7);
        // the 4x4 matrix maps points exactly like the isometry (row-major convention p_a = T_a_b * p_b)
        let rows = rows_from_isometry(&a_from_b);
        let p = Point3::new(0.3, -0.7, 1.1);
        let by_rows: Vec<f64> = (0..3).map(|i| rows[i][0] * p.x + rows[i][1] * p.y + rows[i][2] * p.z + rows[i][3]).collect();
        let by_iso = a_from_b * p;
        prop_assert!((by_iso - Point3::new(by_rows[0], by_rows[1], by_rows[2])).norm() < 1e-12);
    }
}
