//! Calibrated camera models and the vehicle frame.
//!
//! # Frames
//! - **Vehicle frame**, metres: x to the right, y up from the road surface (the road is y = 0),
//!   z forward. Note that this frame is left-handed (as in the paper's figure 2).
//! - **Camera frame** (OpenCV convention): x right, y down, z along the optical axis.
//! - **Pixel frame**: u right, v down, origin at the *centre* of the top-left pixel (OpenCV).
//!
//! A camera's pose is stored as `camera_from_vehicle`: `p_cam = R * flip_y(p_vehicle - C)` where
//! `C` is the optical centre in the vehicle frame, `flip_y` maps the left-handed vehicle frame to a
//! right-handed "forward-looking camera" frame (x right, y down, z forward), and `R` is a proper
//! rotation (identity for a camera looking straight ahead).
//!
//! Flies are projected through each camera's full pinhole + Brown-Conrady model
//! (k1, k2, k3 radial, p1, p2 tangential, OpenCV's convention), so images need no rectification:
//! unlike classical block matching, the Fly Algorithm only ever maps 3-D points *into* images.

use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector3};

/// Pinhole intrinsics in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

/// Brown-Conrady distortion, OpenCV order (k1, k2, p1, p2, k3).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Distortion {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl Distortion {
    pub fn is_zero(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0 && self.k3 == 0.0
    }

    /// Distorted normalised coordinates from ideal (undistorted) normalised coordinates.
    #[inline]
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Inverse of [`Distortion::apply`] by fixed-point iteration (as OpenCV's `undistortPoints`),
    /// refined with Newton steps. Returns `None` if it does not converge, which happens only far
    /// outside the region where the model is valid.
    pub fn remove(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        if self.is_zero() {
            return Some((xd, yd));
        }
        let (mut x, mut y) = (xd, yd);
        for _ in 0..40 {
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
            let dx = 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
            let dy = self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
            if radial.abs() < 1e-6 {
                return None;
            }
            let (nx, ny) = ((xd - dx) / radial, (yd - dy) / radial);
            let step = (nx - x).abs() + (ny - y).abs();
            (x, y) = (nx, ny);
            // Converged (mild distortion: ~10 iterations); the residual check below decides.
            if step < 1e-14 {
                break;
            }
        }
        let (ex, ey) = self.apply(x, y);
        let err = ((ex - xd).powi(2) + (ey - yd).powi(2)).sqrt();
        (err < 1e-9 && x.is_finite() && y.is_finite()).then_some((x, y))
    }
}

/// Why a camera description is unusable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CameraError {
    #[error("{field} must be a finite number (got {value})")]
    NotFinite { field: &'static str, value: f64 },
    #[error("{field} must be positive (got {value})")]
    NotPositive { field: &'static str, value: f64 },
    #[error("image size must be at least 16x16 pixels (got {width}x{height})")]
    TooSmall { width: u32, height: u32 },
    #[error(
        "rotation is not a proper rotation matrix (det = {det:.6}, orthogonality error {ortho:.2e})"
    )]
    NotARotation { det: f64, ortho: f64 },
    #[error("principal point ({cx}, {cy}) lies outside the {width}x{height} image")]
    PrincipalPointOutside {
        cx: f64,
        cy: f64,
        width: u32,
        height: u32,
    },
}

/// A calibrated camera: size, intrinsics, distortion and pose in the vehicle frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    width: u32,
    height: u32,
    intrinsics: Intrinsics,
    distortion: Distortion,
    /// R: forward-looking camera frame -> camera frame.
    rotation: Rotation3<f64>,
    /// Optical centre in the vehicle frame.
    centre: Point3<f64>,
}

/// Maps the left-handed vehicle frame axes to the right-handed forward camera axes.
#[inline]
fn flip_y(v: Vector3<f64>) -> Vector3<f64> {
    Vector3::new(v.x, -v.y, v.z)
}

/// Points closer than this to a camera's image plane (in metres along its axis) are "behind" it.
pub const MIN_CAMERA_DEPTH: f64 = 1e-3;

impl Camera {
    /// Builds a validated camera. `rotation` maps the forward-looking frame (x right, y down,
    /// z forward) to the camera frame; `centre` is the optical centre in the vehicle frame.
    pub fn new(
        width: u32,
        height: u32,
        intrinsics: Intrinsics,
        distortion: Distortion,
        rotation: Matrix3<f64>,
        centre: Point3<f64>,
    ) -> Result<Self, CameraError> {
        if width < 16 || height < 16 {
            return Err(CameraError::TooSmall { width, height });
        }
        let finite = [
            ("fx", intrinsics.fx),
            ("fy", intrinsics.fy),
            ("cx", intrinsics.cx),
            ("cy", intrinsics.cy),
            ("k1", distortion.k1),
            ("k2", distortion.k2),
            ("p1", distortion.p1),
            ("p2", distortion.p2),
            ("k3", distortion.k3),
            ("position.x", centre.x),
            ("position.y", centre.y),
            ("position.z", centre.z),
        ];
        for (field, value) in finite {
            if !value.is_finite() {
                return Err(CameraError::NotFinite { field, value });
            }
        }
        for (field, value) in [("fx", intrinsics.fx), ("fy", intrinsics.fy)] {
            if value <= 0.0 {
                return Err(CameraError::NotPositive { field, value });
            }
        }
        if !(0.0..width as f64).contains(&intrinsics.cx)
            || !(0.0..height as f64).contains(&intrinsics.cy)
        {
            return Err(CameraError::PrincipalPointOutside {
                cx: intrinsics.cx,
                cy: intrinsics.cy,
                width,
                height,
            });
        }
        if rotation.iter().any(|v| !v.is_finite()) {
            return Err(CameraError::NotFinite {
                field: "rotation",
                value: f64::NAN,
            });
        }
        let det = rotation.determinant();
        let ortho = (rotation.transpose() * rotation - Matrix3::identity())
            .abs()
            .max();
        if (det - 1.0).abs() > 1e-4 || ortho > 1e-4 {
            return Err(CameraError::NotARotation { det, ortho });
        }
        Ok(Self {
            width,
            height,
            intrinsics,
            distortion,
            // Not `from_matrix`: its iteration starts at the identity and stays there for a
            // rotation of 180 degrees (a camera turned round was modelled as unrotated). The
            // matrix is orthonormal within 1e-4 (checked above): renormalising from itself only
            // removes that error.
            rotation: {
                let mut r = Rotation3::from_matrix_unchecked(rotation);
                r.renormalize();
                r
            },
            centre,
        })
    }

    pub fn width(&self) -> u32 {
        self.width
    }
    pub fn height(&self) -> u32 {
        self.height
    }
    pub fn intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }
    pub fn distortion(&self) -> &Distortion {
        &self.distortion
    }
    /// Optical centre in the vehicle frame.
    pub fn centre(&self) -> Point3<f64> {
        self.centre
    }
    /// Rotation from the forward-looking frame to this camera's frame.
    pub fn rotation(&self) -> &Rotation3<f64> {
        &self.rotation
    }

    /// The same camera at another image size (for a camera calibrated at one resolution and run at
    /// another with the same field of view): intrinsics scale, distortion is unchanged.
    pub fn scaled_to(&self, width: u32, height: u32) -> Result<Self, CameraError> {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        let k = Intrinsics {
            fx: self.intrinsics.fx * sx,
            fy: self.intrinsics.fy * sy,
            // Pixel centres: the continuous coordinate of pixel i's centre is i + 0.5.
            cx: (self.intrinsics.cx + 0.5) * sx - 0.5,
            cy: (self.intrinsics.cy + 0.5) * sy - 0.5,
        };
        Self::new(
            width,
            height,
            k,
            self.distortion,
            *self.rotation.matrix(),
            self.centre,
        )
    }

    /// A point in the vehicle frame expressed in the camera frame.
    #[inline]
    pub fn camera_from_vehicle(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation * flip_y(p - self.centre))
    }

    /// A point in the camera frame expressed in the vehicle frame.
    #[inline]
    pub fn vehicle_from_camera(&self, p: &Point3<f64>) -> Point3<f64> {
        self.centre + flip_y(self.rotation.inverse() * p.coords)
    }

    /// The affine map `p_cam = A * p_vehicle + b` (what the fly engine evaluates in bulk).
    pub fn camera_from_vehicle_affine(&self) -> (Matrix3<f64>, Vector3<f64>) {
        let flip = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, 1.0));
        let a = self.rotation.matrix() * flip;
        let b = -(a * self.centre.coords);
        (a, b)
    }

    /// Projects a vehicle-frame point to pixel coordinates through the full model. `None` when the
    /// point is behind (or within [`MIN_CAMERA_DEPTH`] of) the camera. The pixel may lie outside
    /// the image; check with [`Camera::contains`].
    #[inline]
    pub fn pixel_from_vehicle(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        self.pixel_from_camera(&self.camera_from_vehicle(p))
    }

    #[inline]
    pub fn pixel_from_camera(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        // NaN depth must be rejected too, hence the explicit check.
        if p.z.is_nan() || p.z <= MIN_CAMERA_DEPTH {
            return None;
        }
        let (xd, yd) = self.distortion.apply(p.x / p.z, p.y / p.z);
        let k = &self.intrinsics;
        Some(Point2::new(k.fx * xd + k.cx, k.fy * yd + k.cy))
    }

    /// Ideal (undistorted) normalised coordinates of a pixel: the direction `(x, y, 1)` in the
    /// camera frame. `None` if the distortion model cannot be inverted there.
    pub fn normalised_from_pixel(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let k = &self.intrinsics;
        self.distortion.remove((u - k.cx) / k.fx, (v - k.cy) / k.fy)
    }

    /// Ray through pixel `(u, v)`: origin (the optical centre) and unit direction, in the vehicle
    /// frame.
    pub fn ray_from_pixel(&self, u: f64, v: f64) -> Option<(Point3<f64>, Vector3<f64>)> {
        let (x, y) = self.normalised_from_pixel(u, v)?;
        let dir_cam = Vector3::new(x, y, 1.0).normalize();
        let dir = flip_y(self.rotation.inverse() * dir_cam);
        Some((self.centre, dir))
    }

    /// The vehicle-frame point seen at pixel `(u, v)` at `depth` metres along the optical axis.
    pub fn vehicle_from_pixel_depth(&self, u: f64, v: f64, depth: f64) -> Option<Point3<f64>> {
        let (x, y) = self.normalised_from_pixel(u, v)?;
        Some(self.vehicle_from_camera(&Point3::new(x * depth, y * depth, depth)))
    }

    /// Whether a pixel position lies inside the image (pixel centres span `0..=w-1`).
    #[inline]
    pub fn contains(&self, px: &Point2<f64>) -> bool {
        px.x >= -0.5
            && px.y >= -0.5
            && px.x < self.width as f64 - 0.5
            && px.y < self.height as f64 - 0.5
    }
}

/// Rotation (forward-looking frame -> camera frame) from angles in degrees: `pitch` tilts the
/// camera down for positive values, `yaw` turns it to the right, `roll` turns the image clockwise.
pub fn rotation_from_angles(pitch_deg: f64, yaw_deg: f64, roll_deg: f64) -> Matrix3<f64> {
    // In the forward camera frame (x right, y down, z forward): pitching down is a rotation about
    // +x of the camera *axes*; the matrix that maps forward-frame coordinates into the pitched
    // frame is the inverse (transpose) of the axes' rotation.
    let axes = Rotation3::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians())
        * Rotation3::from_axis_angle(&Vector3::x_axis(), -pitch_deg.to_radians())
        * Rotation3::from_axis_angle(&Vector3::z_axis(), roll_deg.to_radians());
    *axes.inverse().matrix()
}

/// Two calibrated cameras looking at the same scene.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoRig {
    pub left: Camera,
    pub right: Camera,
}

impl StereoRig {
    /// Whether the rig is rectified: no distortion, the same orientation and vertical
    /// intrinsics, the right camera along the left one's x axis. Only then is a scene point on
    /// the same row of both images (what [`crate::rectification`] measures the residual of).
    pub fn is_rectified(&self) -> bool {
        let (l, r) = (&self.left, &self.right);
        let (kl, kr) = (l.intrinsics(), r.intrinsics());
        let along = l.rotation * (r.centre - l.centre);
        let b = along.norm().max(1e-9);
        l.distortion().is_zero()
            && r.distortion().is_zero()
            && (l.rotation.matrix() - r.rotation.matrix()).abs().max() < 1e-6
            && (kl.fy - kr.fy).abs() < 1e-6 * kl.fy.abs().max(1.0)
            && (kl.cy - kr.cy).abs() < 1e-3
            && along.y.abs() < 1e-6 * b
            && along.z.abs() < 1e-6 * b
    }

    /// Distance between the optical centres, metres.
    pub fn baseline(&self) -> f64 {
        (self.right.centre - self.left.centre).norm()
    }

    /// The same rig moved as one rigid body so that the left camera's optical centre is at
    /// `left_centre` (vehicle frame) with orientation `left_rotation` (forward-looking frame ->
    /// camera frame): how an imported calibration, which knows only where the right camera is
    /// relative to the left one, is placed on the vehicle.
    pub fn placed(
        &self,
        left_centre: Point3<f64>,
        left_rotation: Matrix3<f64>,
    ) -> Result<StereoRig, CameraError> {
        let (l, r) = (&self.left, &self.right);
        // p_right = R_rel p_left + t_rel (camera frames), the rig's invariant.
        let r_rel = r.rotation * l.rotation.inverse();
        let t_rel = r.rotation * flip_y(l.centre - r.centre);
        let left = Camera::new(
            l.width,
            l.height,
            l.intrinsics,
            l.distortion,
            left_rotation,
            left_centre,
        )?;
        let right_rotation = r_rel * left.rotation;
        let right_centre = left_centre - flip_y(right_rotation.inverse() * t_rel);
        let right = Camera::new(
            r.width,
            r.height,
            r.intrinsics,
            r.distortion,
            *right_rotation.matrix(),
            right_centre,
        )?;
        Ok(StereoRig { left, right })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_placed_rig_keeps_its_relative_pose() {
        let k = Intrinsics {
            fx: 700.0,
            fy: 700.0,
            cx: 320.0,
            cy: 240.0,
        };
        let cam = |x: f64, yaw: f64| {
            let rotation = rotation_from_angles(1.0, yaw, 0.5);
            Camera::new(
                640,
                480,
                k,
                Distortion::default(),
                rotation,
                Point3::new(x, 0.0, 0.0),
            )
        };
        let rig = StereoRig {
            left: cam(0.0, 0.0).expect("camera"),
            right: cam(0.5, 1.5).expect("camera"),
        };
        let placed = rig
            .placed(
                Point3::new(-0.06, 1.65, 0.2),
                rotation_from_angles(3.0, 0.0, -1.0),
            )
            .expect("placed");
        assert_eq!(placed.left.centre(), Point3::new(-0.06, 1.65, 0.2));
        assert!((placed.baseline() - 0.5).abs() < 1e-12);
        // A point in the left camera's frame lands on the same right pixel in both rigs.
        for p in [Point3::new(0.3, -0.2, 5.0), Point3::new(-2.0, 1.0, 17.0)] {
            let (a, b) = (
                rig.right
                    .camera_from_vehicle(&rig.left.vehicle_from_camera(&p)),
                placed
                    .right
                    .camera_from_vehicle(&placed.left.vehicle_from_camera(&p)),
            );
            assert!((a - b).norm() < 1e-9, "{a} vs {b}");
        }
    }

    fn camera(dist: Distortion, pitch: f64) -> Camera {
        Camera::new(
            640,
            480,
            Intrinsics {
                fx: 500.0,
                fy: 505.0,
                cx: 321.5,
                cy: 238.0,
            },
            dist,
            rotation_from_angles(pitch, 2.0, -1.0),
            Point3::new(-0.15, 1.2, 0.3),
        )
        .expect("valid camera")
    }

    const DIST: Distortion = Distortion {
        k1: -0.28,
        k2: 0.09,
        p1: 0.0012,
        p2: -0.0008,
        k3: -0.01,
    };

    #[test]
    fn distortion_round_trip_over_the_image() {
        for i in 0..=20 {
            for j in 0..=20 {
                let x = -0.6 + 1.2 * i as f64 / 20.0;
                let y = -0.45 + 0.9 * j as f64 / 20.0;
                let (xd, yd) = DIST.apply(x, y);
                let (xu, yu) = DIST.remove(xd, yd).expect("invertible");
                assert!((xu - x).abs() < 1e-9 && (yu - y).abs() < 1e-9, "{x},{y}");
            }
        }
    }

    #[test]
    fn pixel_ray_pixel_round_trip() {
        let cam = camera(DIST, 5.0);
        for (u, v) in [(0.0, 0.0), (639.0, 479.0), (320.0, 240.0), (17.3, 401.9)] {
            let p = cam
                .vehicle_from_pixel_depth(u, v, 7.5)
                .expect("pixel back-projects");
            let px = cam.pixel_from_vehicle(&p).expect("in front");
            assert!((px.x - u).abs() < 1e-6 && (px.y - v).abs() < 1e-6);
            let (o, d) = cam.ray_from_pixel(u, v).expect("ray");
            let on_ray = o + d * ((p - o).norm());
            assert!((on_ray - p).norm() < 1e-6);
        }
    }

    #[test]
    fn vehicle_frame_axes() {
        // A level camera 1.2 m above the road: a point ahead and above the camera projects above
        // the principal point (smaller v); a point to the right projects right of it.
        let cam = camera(Distortion::default(), 0.0);
        let cam = Camera::new(
            640,
            480,
            *cam.intrinsics(),
            Distortion::default(),
            Matrix3::identity(),
            Point3::new(0.0, 1.2, 0.0),
        )
        .expect("valid");
        let up = cam
            .pixel_from_vehicle(&Point3::new(0.0, 2.2, 10.0))
            .unwrap();
        assert!(up.y < 238.0 && (up.x - 321.5).abs() < 1e-9);
        let right = cam
            .pixel_from_vehicle(&Point3::new(1.0, 1.2, 10.0))
            .unwrap();
        assert!(right.x > 321.5);
        assert!(
            cam.pixel_from_vehicle(&Point3::new(0.0, 1.2, -1.0))
                .is_none()
        );
        // Pitching down moves a straight-ahead point up in the image.
        let pitched = camera(Distortion::default(), 10.0);
        let p = pitched.centre() + Vector3::new(0.0, 0.0, 10.0);
        assert!(pitched.pixel_from_vehicle(&p).unwrap().y < 238.0 - 50.0);
    }

    #[test]
    fn affine_matches_pose() {
        let cam = camera(DIST, 3.0);
        let (a, b) = cam.camera_from_vehicle_affine();
        let p = Point3::new(0.7, 0.4, 6.0);
        let c = cam.camera_from_vehicle(&p);
        assert!((a * p.coords + b - c.coords).norm() < 1e-12);
        assert!((cam.vehicle_from_camera(&c) - p).norm() < 1e-12);
    }

    #[test]
    fn rejects_broken_cameras() {
        let k = Intrinsics {
            fx: 500.0,
            fy: 500.0,
            cx: 320.0,
            cy: 240.0,
        };
        let r = Matrix3::identity();
        let c = Point3::origin();
        let d = Distortion::default();
        assert!(matches!(
            Camera::new(640, 480, Intrinsics { fx: -1.0, ..k }, d, r, c),
            Err(CameraError::NotPositive { field: "fx", .. })
        ));
        assert!(matches!(
            Camera::new(640, 480, Intrinsics { cx: f64::NAN, ..k }, d, r, c),
            Err(CameraError::NotFinite { field: "cx", .. })
        ));
        assert!(matches!(
            Camera::new(640, 480, k, d, r * 2.0, c),
            Err(CameraError::NotARotation { .. })
        ));
        assert!(matches!(
            Camera::new(640, 480, Intrinsics { cx: 900.0, ..k }, d, r, c),
            Err(CameraError::PrincipalPointOutside { .. })
        ));
        assert!(matches!(
            Camera::new(8, 480, k, d, r, c),
            Err(CameraError::TooSmall { .. })
        ));
    }

    #[test]
    fn scaling_keeps_the_field_of_view() {
        let cam = camera(DIST, 0.0);
        let half = cam.scaled_to(320, 240).expect("valid");
        let p = Point3::new(0.5, 0.8, 5.0);
        let a = cam.pixel_from_vehicle(&p).unwrap();
        let b = half.pixel_from_vehicle(&p).unwrap();
        assert!(((a.x + 0.5) / 2.0 - 0.5 - b.x).abs() < 1e-9);
    }
}
