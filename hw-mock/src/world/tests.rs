use super::*;

#[test]
fn box_hit_faces_and_coordinates() {
    let car = Obstacle::car(0.0, 10.0);
    let hit = car
        .intersect(&Ray::towards([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]))
        .expect("hits the rear");
    assert!((hit.t - 10.0).abs() < 1e-12);
    assert_eq!(hit.face, Face::NegZ);
    assert_eq!(hit.normal, [0.0, 0.0, -1.0]);
    assert!(hit.s.abs() < 1e-12 && (hit.h - 1.0).abs() < 1e-12);
    // Missing to the side, and starting inside, see nothing.
    assert!(
        car.intersect(&Ray::towards([3.0, 1.0, 0.0], [0.0, 0.0, 1.0]))
            .is_none()
    );
    assert!(
        car.intersect(&Ray::towards([0.0, 1.0, 12.0], [0.0, 0.0, 1.0]))
            .is_none()
    );
}

#[test]
fn cylinder_hit_front_and_cap() {
    let p = Obstacle::pedestrian(0.0, 4.0);
    let hit = p
        .intersect(&Ray::towards([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]))
        .expect("hits");
    assert!((hit.t - 3.75).abs() < 1e-12);
    assert_eq!(hit.face, Face::Round);
    assert!(hit.s.abs() < 1e-12);
    let top = p
        .intersect(&Ray::towards([0.0, 3.0, 0.0], [0.0, -1.25, 4.0]))
        .expect("hits the top");
    assert_eq!(top.face, Face::Cap);
    assert!((top.point[1] - 1.75).abs() < 1e-12);
}

#[test]
fn invalid_obstacles_are_never_hit() {
    let bad = [
        Obstacle::Cylinder {
            x: 0.0,
            z: 4.0,
            radius: -1.0,
            height: 1.0,
            material: *Obstacle::pedestrian(0.0, 0.0).material(),
        },
        Obstacle::Box {
            min: [0.0, 0.0, f64::NAN],
            max: [1.0, 1.0, 5.0],
            material: *Obstacle::car(0.0, 0.0).material(),
        },
    ];
    for o in bad {
        assert!(!o.is_valid());
        assert!(
            o.intersect(&Ray::towards([0.0, 0.5, 0.0], [0.0, 0.0, 1.0]))
                .is_none()
        );
        assert!(o.bounding_sphere().is_none());
    }
}

#[test]
fn lane_occupancy() {
    assert!(Scene::with(vec![Obstacle::pedestrian(0.0, 4.0)]).obstacle_in_lane());
    assert!(Scene::with(vec![Obstacle::pedestrian(1.9, 4.0)]).obstacle_in_lane());
    assert!(!Scene::with(vec![Obstacle::pedestrian(2.2, 4.0)]).obstacle_in_lane());
    assert!(!Scene::with(vec![Obstacle::car(0.0, -10.0)]).obstacle_in_lane());
    assert!(!Scene::empty().obstacle_in_lane());
    // The roadside never intrudes into the lane.
    assert!(!Scene::with(roadside()).obstacle_in_lane());
}

#[test]
fn road_has_marks_where_promised() {
    let fine = 1e-4;
    let mark = road_albedo(1.75, 1.5, fine, fine);
    let gap = road_albedo(1.75, 6.0, fine, fine);
    let grass = road_albedo(-8.0, 10.0, fine, fine);
    assert!(mark[0] > 180.0, "{mark:?}");
    assert!(gap[0] < 170.0, "{gap:?}");
    assert!(grass[1] > grass[0] && grass[1] > grass[2], "{grass:?}");
}
