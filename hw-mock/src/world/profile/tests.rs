use super::*;
use crate::world::Face;

static ARC: [Segment; 3] = [
    Segment::straight(20.0),
    Segment::arc(60.0, 1.0 / 40.0),
    Segment::straight(100.0),
];
static CLOTHOID: [Segment; 1] = [Segment::clothoid(60.0, 0.0, 1.0 / 300.0)];
static CONSTANT: [Segment; 1] = [Segment::arc(100.0, 1.0 / 60.0)];
static S_BEND: [Segment; 3] = [
    Segment::clothoid(25.0, 0.0, 1.0 / 80.0),
    Segment::clothoid(25.0, 1.0 / 80.0, -1.0 / 80.0),
    Segment::clothoid(25.0, -1.0 / 80.0, 0.0),
];

fn leak(profile: &'static [Segment]) -> &'static Road {
    Box::leak(Box::new(Road::new(profile)))
}

#[test]
fn an_arc_integrates_to_its_circle() {
    let road = leak(&ARC);
    let k = 1.0 / 40.0;
    for along in [-10.0, 0.0, 10.0, 20.0, 20.5, 33.3, 60.0, 79.5] {
        let (x, z) = road.point(along, 0.0);
        let (ex, ez) = if along <= 20.0 {
            (0.0, along)
        } else {
            let (x, z) = bend::point(k, along - 20.0, 0.0);
            (x, z + 20.0)
        };
        assert!(
            (x - ex).abs() < 1e-9 && (z - ez).abs() < 1e-9,
            "{along}: ({x}, {z}) vs ({ex}, {ez})"
        );
        let heading = (along - 20.0).max(0.0) * k;
        assert!((road.heading(along) - heading).abs() < 1e-12, "{along}");
        assert_eq!(road.curvature(along), if along < 20.0 { 0.0 } else { k });
    }
    // Off the centre line too, and back.
    for (along, offset) in [
        (30.0, 1.5),
        (70.0, -5.5),
        (120.0, 3.0),
        (5.0, -2.0),
        (-20.0, 4.0),
    ] {
        let (x, z) = road.point(along, offset);
        let (a, o) = road.locate(x, z);
        assert!(
            (a - along).abs() < 1e-9 && (o - offset).abs() < 1e-9,
            "({along}, {offset}) -> ({a}, {o})"
        );
    }
}

#[test]
fn a_small_angle_clothoid_is_the_cubic() {
    // k = c s: heading c s^2 / 2, and for a small angle x = -c s^3 / 6 (left), z = s.
    let road = leak(&CLOTHOID);
    let c = 1.0 / 300.0 / 60.0;
    for s in [5.0, 17.5, 30.0, 45.25, 60.0] {
        let (x, z) = road.point(s, 0.0);
        // Exact at the nodes, the cells' arcs in between (within c CELL^2 / 8).
        let heading = c * s * s / 2.0;
        let within = if s.fract() == 0.0 {
            1e-12
        } else {
            1.01 * c * CELL * CELL / 8.0
        };
        assert!((road.heading(s) - heading).abs() <= within, "{s}");
        assert!((road.curvature(s) - c * s).abs() < 1e-15, "{s}");
        // The next terms: x + c^3 s^7 / 336, z - c^2 s^5 / 40; the chain of arcs is within
        // a millimetre of the clothoid.
        let (ex, ez) = (-c * s.powi(3) / 6.0, s);
        let (tx, tz) = (c.powi(3) * s.powi(7) / 336.0, c * c * s.powi(5) / 40.0);
        assert!((x - ex).abs() < tx + 1e-3, "{s}: x {x} vs {ex}");
        assert!((z - ez).abs() < tz + 1e-3, "{s}: z {z} vs {ez}");
    }
    // After the profile the road runs on at its last curvature.
    assert_eq!(road.curvature(100.0), 1.0 / 300.0);
}

#[test]
fn a_constant_profile_is_the_bend() {
    let road = leak(&CONSTANT);
    let k = 1.0 / 60.0;
    assert_eq!(road.constant(), Some(k));
    for (along, offset) in [(0.0, 0.0), (12.0, 1.5), (45.0, -5.5), (80.0, 7.0)] {
        assert_eq!(road.point(along, offset), bend::point(k, along, offset));
        assert_eq!(road.heading(along), bend::heading(k, along));
        let (x, z) = bend::point(k, along, offset);
        assert_eq!(road.locate(x, z), bend::locate(k, x, z));
    }
    assert_eq!(road.props(), bend::bent(k, &roadside()));
    assert_eq!(
        road.lay([-0.9, 0.0, 10.0], [0.9, 1.5, 14.2], Material::CAR),
        vec![Obstacle::Bent {
            curvature: k,
            min: [-0.9, 0.0, 10.0],
            max: [0.9, 1.5, 14.2],
            material: Material::CAR
        }]
    );
}

#[test]
fn road_coordinates_round_trip_on_an_s_bend() {
    let road = leak(&S_BEND);
    assert_eq!(road.curvature(37.5), 0.0);
    assert!(road.heading(75.0).abs() < 1e-12, "{}", road.heading(75.0));
    for along in (-30..200).map(|i| f64::from(i) * 0.7) {
        for offset in [-6.0, -2.7, 0.0, 0.3, 1.8, 4.0] {
            let (x, z) = road.point(along, offset);
            let (a, o) = road.locate(x, z);
            assert!(
                (a - along).abs() < 1e-8 && (o - offset).abs() < 1e-8,
                "({along}, {offset}) -> ({x}, {z}) -> ({a}, {o})"
            );
        }
    }
}

#[test]
fn posts_stand_on_both_kerbs_every_fifty_metres() {
    let road = leak(&S_BEND);
    let posts: Vec<_> = road.posts().collect();
    assert_eq!(
        &posts[..4],
        &[(20.0, -2.4), (20.0, 2.4), (70.0, -2.4), (70.0, 2.4)]
    );
    assert!(posts.iter().all(|p| p.0 < END));
    // Laid as thin boxes: a ray down onto a post's top meets it there, 1 m up, and a
    // horizontal ray from the centre line towards it meets its inner face 2.35 m across.
    let props = road.props();
    for &(along, offset) in &posts[..4] {
        let (x, z) = road.point(along, offset);
        let top = props
            .iter()
            .filter_map(|o| o.intersect(&Ray::towards([x, 3.0, z], [0.0, -1.0, 0.0])))
            .min_by(|a, b| a.t.total_cmp(&b.t))
            .expect("the post is there");
        assert!((top.point[1] - 1.0).abs() < 1e-9, "{top:?}");
        assert_eq!(top.face, Face::Horizontal);
        let (cx, cz) = road.point(along, 0.0);
        let (tx, tz) = road.point(along, offset.signum() * 3.0);
        let side = props
            .iter()
            .filter_map(|o| o.intersect(&Ray::towards([cx, 0.5, cz], [tx - cx, 0.0, tz - cz])))
            .min_by(|a, b| a.t.total_cmp(&b.t))
            .expect("the post's side");
        assert!((side.t - 2.35).abs() < 1e-6, "{side:?}");
        let (a, o) = road.locate(side.point[0], side.point[2]);
        assert!((a - along).abs() < 1e-6 && (o.abs() - 2.35).abs() < 1e-6);
    }
    // Between posts the same ray reaches the guard rail (outside of the left bend: right).
    let (cx, cz) = road.point(30.0, 0.0);
    let (tx, tz) = road.point(30.0, 4.0);
    let rail = props
        .iter()
        .filter_map(|o| o.intersect(&Ray::towards([cx, 0.5, cz], [tx - cx, 0.0, tz - cz])))
        .min_by(|a, b| a.t.total_cmp(&b.t))
        .expect("the guard rail");
    assert!((rail.t - RAIL[0]).abs() < 1e-6, "{rail:?}");
    // Every piece is valid and its bounds hold it.
    for o in &props {
        assert!(o.is_valid(), "{o:?}");
    }
}

#[test]
fn a_laid_box_is_one_box_across_its_pieces() {
    // A wall 30 m long along the S-bend, cut into pieces: rays from the centre line meet
    // its face at its offset wherever they look, and no cut shows as a face.
    let road = leak(&S_BEND);
    let wall = road.lay(
        [4.0, 0.0, 5.0],
        [4.2, 2.0, 35.0],
        Material {
            colour: [150, 150, 150],
            pattern: Pattern::Bricks,
            seed: 1,
        },
    );
    assert!(wall.len() > 1);
    for i in 0..=120 {
        let along = 5.5 + 0.24 * f64::from(i);
        let (cx, cz) = road.point(along, 0.0);
        let (tx, tz) = road.point(along, 4.1);
        let hit = wall
            .iter()
            .filter_map(|o| o.intersect(&Ray::towards([cx, 1.0, cz], [tx - cx, 0.0, tz - cz])))
            .min_by(|a, b| a.t.total_cmp(&b.t))
            .expect("the wall");
        assert_eq!(hit.face, Face::NegX, "{along}");
        assert!((hit.t - 4.0).abs() < 1e-6, "{along}: {hit:?}");
        assert!((hit.s - (along - 20.0)).abs() < 1e-6, "{along}: {hit:?}");
    }
    // Its end faces are where it ends.
    let (cx, cz) = road.point(2.0, 4.1);
    let (tx, tz) = road.point(6.0, 4.1);
    let end = wall
        .iter()
        .filter_map(|o| o.intersect(&Ray::towards([cx, 1.0, cz], [tx - cx, 0.0, tz - cz])))
        .min_by(|a, b| a.t.total_cmp(&b.t))
        .expect("the wall's end");
    assert_eq!(end.face, Face::NegZ);
    let (a, _) = road.locate(end.point[0], end.point[2]);
    assert!((a - 5.0).abs() < 1e-6, "{a}");
}
