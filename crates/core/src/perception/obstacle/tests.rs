use super::cluster::{cell_centre, gcd, mad, ordered};
use super::*;

/// Flies at `depths`, each in its own cell.
fn flies(depths: &[f32]) -> Vec<Unique> {
    depths
        .iter()
        .enumerate()
        .map(|(i, &z)| Unique {
            z,
            along: z,
            // A diagonal: every fly its own row and column, 8 px apart.
            cell: (i as u32) << 16 | i as u32,
            u: 8.0 * i as f32,
            v: 8.0 * i as f32,
            x: 0.1 * i as f32,
            h: 1.0,
            index: i as u32,
        })
        .collect()
}

/// The cluster's flies' indices.
fn cluster(u: &[Unique], c: &ObstacleConfig) -> Option<Vec<u32>> {
    let mut members = Vec::new();
    let mut cells = CellSet::new((640, 480), c.cell_px);
    nearest_cluster(u, c, 400.0, &mut cells, &mut members)?;
    let mut ids: Vec<u32> = members.iter().map(|m| m.index).collect();
    ids.sort_unstable();
    Some(ids)
}

#[test]
fn ordered_bits_sort_as_total_cmp() {
    let v = [
        f32::NEG_INFINITY,
        -3.5e7,
        -1.0,
        -1e-40,
        -0.0,
        0.0,
        1e-40,
        0.25,
        1.0,
        7.0e5,
        f32::INFINITY,
    ];
    for a in v {
        for b in v {
            assert_eq!(ordered(a).cmp(&ordered(b)), a.total_cmp(&b), "{a} vs {b}");
        }
    }
}

#[test]
fn cells_are_counted_once_and_the_set_is_empty_again_after() {
    let mut set = CellSet::new((640, 480), 8);
    let cell = |row: u32, column: u32| (row << 16) | column;
    let one_row = [cell(3, 1), cell(3, 2), cell(3, 1), cell(3, 79)];
    assert_eq!(set.count(one_row.into_iter()), (3, false));
    let two_rows = [cell(3, 1), cell(59, 1), cell(3, 1)];
    assert_eq!(set.count(two_rows.into_iter()), (2, true));
    // Nothing left over from the calls before.
    assert_eq!(set.count([cell(3, 2)].into_iter()), (1, false));
    assert_eq!(set.count([].into_iter()), (0, false));
    // Past the image: its last row and column.
    assert_eq!(
        set.count([cell(500, 900), cell(60, 80)].into_iter()),
        (1, false)
    );
}

#[test]
fn the_median_absolute_deviation_is_that_of_the_sorted_values() {
    let mut v = [5.0, -1.0, 2.0, 9.0, 2.5, 0.0, 4.0];
    // Median 2.5; deviations 2.5 3.5 0.5 6.5 0 2.5 1.5: median 2.5.
    assert_eq!(mad(&mut v), 2.5);
    assert_eq!(mad(&mut []), 0.0);
    assert_eq!(mad(&mut [3.0]), 0.0);
}

#[test]
fn the_nearest_window_with_enough_flies_is_the_cluster() {
    let c = ObstacleConfig {
        min_flies: 3,
        min_cells: 3,
        ..ObstacleConfig::default()
    };
    // Two strays at 2 and 3 m, then three flies within 2 px of disparity (0.125 m) at
    // 5 m, then a wall at 9 m.
    let u = flies(&[2.0, 3.0, 5.0, 5.05, 5.1, 9.0, 9.0, 9.0, 9.0]);
    assert_eq!(cluster(&u, &c), Some(vec![2, 3, 4]));
    // Without the third fly at 5 m, the wall.
    let u = flies(&[2.0, 3.0, 5.0, 5.1, 9.0, 9.0, 9.0, 9.0]);
    assert_eq!(cluster(&u, &c), Some(vec![4, 5, 6, 7]));
    assert_eq!(cluster(&flies(&[1.0, 2.0]), &c), None);
}

#[test]
fn flies_crowding_on_one_place_of_the_image_are_no_obstacle() {
    let c = ObstacleConfig {
        min_flies: 3,
        min_cells: 2,
        ..ObstacleConfig::default()
    };
    // Five flies at 1.1 m on one cell (a false match), three at 2 m in one column (one
    // vertical edge), then a cluster over two cells.
    let mut u = flies(&[1.1, 1.1, 1.1, 1.1, 1.1, 2.0, 2.0, 2.0, 6.0, 6.05, 6.1]);
    for f in &mut u[..5] {
        f.cell = 77;
    }
    for (row, f) in u[5..8].iter_mut().enumerate() {
        f.cell = (row as u32) << 16 | 40;
        f.u = 320.5 + 0.5 * row as f32;
        f.x = 0.01 * row as f32;
    }
    u[9].cell = u[8].cell;
    assert_eq!(cluster(&u, &c), Some(vec![8, 9, 10]));
}

#[test]
fn chance_matches_scattered_across_the_image_are_no_obstacle() {
    let c = ObstacleConfig {
        min_flies: 4,
        min_cells: 2,
        ..ObstacleConfig::default()
    };
    // Six flies at one depth, 0.9 m apart laterally: never four within a car's width (2 m).
    let mut u = flies(&[3.0; 6]);
    for (i, f) in u.iter_mut().enumerate() {
        f.x = -2.25 + 0.9 * i as f32;
    }
    assert_eq!(cluster(&u, &c), None);
    // Packed within 1.9 m, they are one.
    for (i, f) in u.iter_mut().enumerate() {
        f.x = -0.95 + 0.38 * i as f32;
    }
    assert_eq!(cluster(&u, &c), Some((0..6).collect()));
}

#[test]
fn a_cluster_is_two_pixels_of_disparity_deep() {
    let c = ObstacleConfig {
        min_flies: 2,
        min_cells: 2,
        ..ObstacleConfig::default()
    };
    // f B = 400: at 20 m two pixels are 2 * 400 / 400 = 2 m of depth.
    assert_eq!(cluster(&flies(&[20.0, 21.9]), &c), Some(vec![0, 1]));
    assert_eq!(cluster(&flies(&[20.0, 22.1]), &c), None);
    // Near the vehicle, at least min_cluster_depth.
    assert_eq!(cluster(&flies(&[2.0, 2.09]), &c), Some(vec![0, 1]));
    assert_eq!(cluster(&flies(&[2.0, 2.11]), &c), None);
}

/// The trunk phantom of KITTI odometry 00 frame 1: 1.57-1.95 m up, nothing of it lower;
/// a car's lowest flies are 0.3-0.5 m up.
#[test]
fn a_cluster_floating_above_the_road_is_no_obstacle() {
    let c = ObstacleConfig::default();
    let mut u = flies(&[8.1; 12]);
    for (i, f) in u.iter_mut().enumerate() {
        f.h = 1.57 + 0.03 * i as f32;
    }
    assert!(!reaches_the_road(&u, &c));
    u[7].h = 0.45;
    assert!(reaches_the_road(&u, &c));
    u[7].h = 1.19;
    assert!(reaches_the_road(&u, &c), "just below the bound");
    let high = ObstacleConfig {
        max_bottom: 2.0,
        ..c
    };
    assert!(reaches_the_road(&flies(&[8.1; 12]), &high));
    assert!(!reaches_the_road(&[], &c), "no flies, no obstacle");
}

#[test]
fn a_verified_fly_holds_unless_the_line_or_the_dense_window_refutes_it() {
    let c = ObstacleConfig::default();
    let never = || -> Option<bool> { panic!("the dense window is asked only for a rival") };
    // Unique along the line: holds, without asking the dense window.
    assert!(holds(0.2, &c, never));
    // A better match elsewhere on the line: refuted, whatever the window says.
    assert!(!holds(c.max_line_ambiguity + 0.1, &c, || Some(true)));
    // A rival on the line: the dense window arbitrates; no verdict leaves the line's.
    assert!(holds(0.7, &c, || Some(true)));
    assert!(!holds(0.7, &c, || Some(false)));
    assert!(holds(0.7, &c, || None));
    let off = ObstacleConfig {
        dense_check: false,
        ..c
    };
    assert!(holds(0.7, &off, never));
    // A cluster: half of the verified flies must hold. Five of six on hw-mock's
    // pedestrian (one at its silhouette, where the window sees the road behind) is an
    // obstacle; a row of trunks matched a period away (every fly a rival the window
    // refutes) is not.
    let votes = |flies: &[(f64, Option<bool>)]| {
        let hold = flies.iter().filter(|&&(a, d)| holds(a, &c, || d)).count();
        2 * hold >= flies.len()
    };
    let pedestrian = [
        (0.18, None),
        (0.01, None),
        (0.41, None),
        (0.75, Some(false)),
        (0.15, None),
        (0.04, None),
    ];
    assert!(votes(&pedestrian));
    assert!(!votes(&[(0.8, Some(false)); 6]));
    assert!(!votes(
        &[
            (0.3, None),
            (0.9, None),
            (0.6, Some(false)),
            (0.7, Some(false))
        ][..3]
    ));
}

#[test]
fn the_stride_visits_every_fly_once() {
    for len in [1, 2, 16, 5000, 7919, 7919 * 2, 15838 * 7907] {
        let stride = stride_for(len);
        assert_eq!(gcd(stride, len), 1, "{len}: stride {stride}");
    }
    let len = 5000;
    let stride = stride_for(len);
    let mut seen = vec![false; len];
    let mut i = 0;
    for _ in 0..len {
        assert!(!seen[i], "{i} twice");
        seen[i] = true;
        // (i + stride) % len, without a division: stride < len.
        i += stride;
        if i >= len {
            i -= len;
        }
    }
}

#[test]
fn a_config_that_cannot_work_is_named() {
    let bad = ObstacleConfig {
        min_height: 2.0,
        max_height: 1.0,
        ..ObstacleConfig::default()
    };
    assert_eq!(
        bad.validate().map_err(|e| e.key),
        Err("obstacle.max_height")
    );
    let bad = ObstacleConfig {
        min_flies: 0,
        ..ObstacleConfig::default()
    };
    assert_eq!(bad.validate().map_err(|e| e.key), Err("obstacle.min_flies"));
    let bad = ObstacleConfig {
        max_bottom: 0.2,
        ..ObstacleConfig::default()
    };
    assert_eq!(
        bad.validate().map_err(|e| e.key),
        Err("obstacle.max_bottom")
    );
    assert_eq!(ObstacleConfig::default().validate(), Ok(()));
}

/// A car's rear at 13.7 m: the flies on its left edge read 13.0 m, on its right 14.2 m, on its
/// plate 13.6-13.8 m. However many flies a sample meets on one pile, the centre counts each
/// cell once.
#[test]
fn the_centre_counts_each_cell_once() {
    let mut scratch = Vec::with_capacity(64);
    let cluster = |left: usize, right: usize| {
        let mut depths = vec![13.0; left];
        depths.extend(std::iter::repeat_n(14.2, right));
        depths.extend([13.6, 13.7, 13.8]);
        let mut u = flies(&depths);
        // Each pile on one cell of its own.
        for f in u.iter_mut() {
            if f.z == 13.0 {
                f.cell = 1;
            } else if f.z == 14.2 {
                f.cell = 2;
            }
        }
        u
    };
    let mut many_left = cluster(20, 2);
    let mut many_right = cluster(2, 20);
    assert_eq!(cell_centre(&mut many_left, &mut scratch), 13.7);
    assert_eq!(cell_centre(&mut many_right, &mut scratch), 13.7);
    assert_eq!(cell_centre(&mut [], &mut scratch), 0.0);
}

/// A car 9.7 m ahead whose unique flies pile on its right edge (14 of 20, in three cells of one
/// column) with the rest on its left edge and plate: one cluster, as wide as the car. The
/// right edge alone is one vertical edge, no obstacle.
#[test]
fn a_car_whose_flies_pile_on_one_edge_is_as_wide_as_its_cells() {
    let c = ObstacleConfig::default();
    let mut u = flies(&[9.7; 20]);
    for (i, f) in u.iter_mut().enumerate() {
        if i < 14 {
            // Three cells down the right edge, one column.
            let row = 20 + (i % 3) as u32;
            f.cell = (row << 16) | 50;
            f.u = 400.0 + 0.1 * (i % 3) as f32;
            f.v = 8.0 * row as f32;
            f.x = 0.95;
        } else {
            // The left edge and the plate, a cell each.
            f.cell = ((20 + i as u32 % 3) << 16) | (30 + i as u32);
            f.u = 8.0 * (30 + i) as f32;
            f.v = 8.0 * (20 + i % 3) as f32;
            f.x = -0.8 + 0.2 * (i - 14) as f32;
        }
    }
    assert_eq!(cluster(&u, &c), Some((0..20).collect()));
    assert_eq!(cluster(&u[..14], &c), None);
}

#[test]
fn beside_the_corridor_an_obstacle_is_where_its_inner_edge_is() {
    // A car parked right of the path, its inner side 2.25 m off it: a few flies on that side,
    // most on its rear face out to the band's edge at 3 m (hw-mock's between-parked-cars).
    let xs = [
        2.25, 2.26, 2.9, 2.95, 2.6, 2.8, 2.85, 2.7, 2.9, 2.75, 2.98, 2.88,
    ];
    let mut car = flies(&[10.0; 12]);
    for (u, x) in car.iter_mut().zip(xs) {
        u.x = x;
    }
    let mut scratch = Vec::new();
    // The decile nearest the path: its inner side, where the quartile read 2.6 m.
    assert_eq!(
        across(&car, Some((1.2, 3.0)), &mut scratch),
        f64::from(2.26f32)
    );
    // The same car left of the path.
    for u in &mut car {
        u.x = -u.x;
    }
    assert_eq!(
        across(&car, Some((-3.0, -1.2)), &mut scratch),
        f64::from(-2.26f32)
    );
    // In the corridor: the median.
    assert_eq!(across(&car, None, &mut scratch), f64::from(-2.8f32));
}
