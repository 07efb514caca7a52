//! Where everything is, in the sample's frame: the turntable turns the sample, so a device at
//! world azimuth a appears at a − θt. Cameras, lamps and the laser are placed from the rig
//! spec and the axis angles of the world snapshot.

use std::collections::BTreeMap;

use glam::{Mat3A, Vec3A};
use stagehand_devices::fixture_pose::FixturePose;
use stagehand_devices::lens::{BrownConrady, Intrinsics};
use stagehand_devices::rig::{AxisRole, CameraSpec, RigSpec};

/// Axis angles that move the optics, in degrees (a missing axis reads 0°).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigAngles {
    /// Turntable angle θt: rotates the sample about z.
    pub turntable_deg: f64,
    /// Light arc angle: azimuth of the lamps and the laser mount.
    pub light_arc_deg: f64,
}

impl RigAngles {
    /// Reads the angles of the axes with the turntable and light-arc roles.
    pub fn from_world(rig: &RigSpec, axes: &BTreeMap<String, f64>) -> RigAngles {
        let angle = |role| {
            rig.axis_with_role(role)
                .and_then(|a| axes.get(&a.id))
                .copied()
                .unwrap_or(0.0)
        };
        RigAngles {
            turntable_deg: angle(AxisRole::Turntable),
            light_arc_deg: angle(AxisRole::LightArc),
        }
    }
}

/// From the world frame into the sample frame: by −θt about z (the turntable), then into the
/// fixture's own frame when it was placed tilted, turned or shifted ([`FixturePose`]). Points
/// and directions differ only when the fixture is shifted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ToSample {
    cos: f32,
    sin: f32,
    /// The placement's inverse rotation and its centre in the turntable frame; `None` when the
    /// fixture lies flat and centred (the turntable rotation alone, bit for bit as before).
    placed: Option<(Mat3A, Vec3A)>,
}

impl ToSample {
    /// The rotation for turntable angle `turntable_deg`, the fixture flat and centred.
    pub fn new(turntable_deg: f64) -> ToSample {
        let a = -turntable_deg.to_radians();
        ToSample {
            cos: a.cos() as f32,
            sin: a.sin() as f32,
            placed: None,
        }
    }

    /// The transform for turntable angle `turntable_deg` with the fixture placed as `pose`.
    pub fn placed(turntable_deg: f64, pose: &FixturePose) -> ToSample {
        let mut t = ToSample::new(turntable_deg);
        if !pose.is_flat_centred() {
            let r = pose.rotation();
            // Columns of Rᵀ are the rows of R.
            let col = |i: usize| Vec3A::new(r[i][0] as f32, r[i][1] as f32, r[i][2] as f32);
            let o = pose.offset_mm();
            t.placed = Some((
                Mat3A::from_cols(col(0), col(1), col(2)),
                Vec3A::new(o[0] as f32, o[1] as f32, o[2] as f32),
            ));
        }
        t
    }

    fn turn(&self, v: Vec3A) -> Vec3A {
        Vec3A::new(
            self.cos * v.x - self.sin * v.y,
            self.sin * v.x + self.cos * v.y,
            v.z,
        )
    }

    /// A world point in the sample frame.
    pub fn point(&self, p: Vec3A) -> Vec3A {
        match &self.placed {
            None => self.turn(p),
            Some((r_inv, centre)) => *r_inv * (self.turn(p) - *centre),
        }
    }

    /// A world direction in the sample frame.
    pub fn dir(&self, v: Vec3A) -> Vec3A {
        match &self.placed {
            None => self.turn(v),
            Some((r_inv, _)) => *r_inv * self.turn(v),
        }
    }
}

/// World position of a device at (azimuth, elevation, distance) about the origin.
pub fn spherical(azimuth_deg: f64, elevation_deg: f64, distance_mm: f64) -> Vec3A {
    let (a, e) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vec3A::new(
        (distance_mm * e.cos() * a.cos()) as f32,
        (distance_mm * e.cos() * a.sin()) as f32,
        (distance_mm * e.sin()) as f32,
    )
}

/// Horizontal unit vector perpendicular to the vertical plane at azimuth `azimuth_deg`
/// (the light arc's tangent at its foot; the laser fan spreads along it).
pub fn horizontal_tangent(azimuth_deg: f64) -> Vec3A {
    let a = azimuth_deg.to_radians();
    Vec3A::new(-a.sin() as f32, a.cos() as f32, 0.0)
}

/// Rotates `v` by `angle_rad` about the unit `axis` (Rodrigues).
pub fn rotate_about(v: Vec3A, axis: Vec3A, angle_rad: f32) -> Vec3A {
    let (s, c) = angle_rad.sin_cos();
    v * c + axis.cross(v) * s + axis * axis.dot(v) * (1.0 - c)
}

/// A camera looking at the origin with image up ≈ +z, in the sample frame: a pinhole plus
/// Brown–Conrady lens distortion about the principal point (see [`stagehand_devices::lens`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// Centre of projection.
    pub origin: Vec3A,
    /// Optical axis.
    pub forward: Vec3A,
    /// Image +x direction.
    pub right: Vec3A,
    /// Image up direction (image rows grow downward).
    pub up: Vec3A,
    /// Focal length in pixels.
    pub focal_px: f32,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Principal point, pixels from the left edge.
    pub principal_x: f32,
    /// Principal point, pixels from the top edge.
    pub principal_y: f32,
    /// Brown–Conrady lens distortion (identity for a pinhole).
    pub lens: BrownConrady,
}

impl CameraPose {
    /// The camera of `spec` with the turntable at `to_sample`.
    pub fn new(spec: &CameraSpec, to_sample: ToSample) -> CameraPose {
        CameraPose::mounted(spec, [0.0; 3], [0.0; 3], to_sample)
    }

    /// The camera of `spec` moved by `position_mm` (world frame) and turned by `rotation_deg`
    /// about its own right, up and forward axes, with the turntable at `to_sample`: a camera
    /// as built, off its nominal mount.
    pub fn mounted(
        spec: &CameraSpec,
        rotation_deg: [f64; 3],
        position_mm: [f64; 3],
        to_sample: ToSample,
    ) -> CameraPose {
        let nominal = spherical(spec.azimuth_deg, spec.elevation_deg, spec.distance_mm);
        let mut forward = (-nominal).normalize_or(-Vec3A::Z);
        let mut right = forward
            .cross(Vec3A::Z)
            .try_normalize()
            .unwrap_or_else(|| horizontal_tangent(spec.azimuth_deg));
        let mut up = right.cross(forward);
        let pos = nominal
            + Vec3A::new(
                position_mm[0] as f32,
                position_mm[1] as f32,
                position_mm[2] as f32,
            );
        for (axis, deg) in [
            (right, rotation_deg[0]),
            (up, rotation_deg[1]),
            (forward, rotation_deg[2]),
        ] {
            if deg != 0.0 {
                let a = (deg as f32).to_radians();
                forward = rotate_about(forward, axis, a);
                right = rotate_about(right, axis, a);
                up = rotate_about(up, axis, a);
            }
        }
        let intrinsics = Intrinsics::of(spec);
        CameraPose {
            origin: to_sample.point(pos),
            forward: to_sample.dir(forward),
            right: to_sample.dir(right),
            up: to_sample.dir(up),
            focal_px: intrinsics.focal_px as f32,
            width: spec.width,
            height: spec.height,
            principal_x: 0.5 * spec.width as f32 + spec.cx as f32,
            principal_y: 0.5 * spec.height as f32 + spec.cy as f32,
            lens: intrinsics.lens,
        }
    }

    /// Unit ray direction through image point (x, y) in pixels from the top-left corner: the
    /// point is undistorted (Newton inversion of the lens model, [`BrownConrady::undistort`])
    /// and the pinhole ray through the result returned. A pinhole lens skips the inversion.
    #[inline]
    pub fn ray(&self, x: f32, y: f32) -> Vec3A {
        if self.lens.is_identity() {
            let dx = x - self.principal_x;
            let dy = self.principal_y - y;
            return (self.forward * self.focal_px + self.right * dx + self.up * dy).normalize();
        }
        self.ray_through(self.undistorted(x, y))
    }

    /// The undistorted normalised coordinates (x/z, y/z with image y down) of image point
    /// (x, y), in the single precision rays are made from: the lens inversion, which depends
    /// on neither the pose nor the frame (`pixel_samples` tabulates it per camera).
    #[inline]
    pub fn undistorted(&self, x: f32, y: f32) -> [f32; 2] {
        let dx = x - self.principal_x;
        let dy = self.principal_y - y;
        let f = f64::from(self.focal_px);
        let ((u, v), _) = self.lens.undistort(f64::from(dx) / f, -f64::from(dy) / f);
        [u as f32, v as f32]
    }

    /// Unit ray direction through undistorted normalised coordinates ([`Self::undistorted`]).
    #[inline]
    pub fn ray_through(&self, [u, v]: [f32; 2]) -> Vec3A {
        (self.forward + self.right * u - self.up * v).normalize()
    }

    /// Image position (x, y) in pixels of a sample-frame point, if it is in front: the pinhole
    /// projection, then the lens's forward distortion.
    pub fn project(&self, p: Vec3A) -> Option<(f32, f32)> {
        let v = p - self.origin;
        let z = v.dot(self.forward);
        if z <= 0.0 {
            return None;
        }
        if self.lens.is_identity() {
            let x = self.principal_x + self.focal_px * v.dot(self.right) / z;
            let y = self.principal_y - self.focal_px * v.dot(self.up) / z;
            return Some((x, y));
        }
        let u = f64::from(v.dot(self.right)) / f64::from(z);
        let w = -f64::from(v.dot(self.up)) / f64::from(z);
        let (xd, yd) = self.lens.distort(u, w);
        let f = f64::from(self.focal_px);
        Some((
            (f64::from(self.principal_x) + f * xd) as f32,
            (f64::from(self.principal_y) + f * yd) as f32,
        ))
    }
}

/// A camera's geometry in OpenCV's convention, in the world frame at turntable 0° (the rig
/// frame processing calibrates: origin at the table centre on the sample top, z up, x along
/// the table's 0°): the ground truth geometric calibration is evaluated against.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct OpenCvCamera {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels, pixel centres at integers.
    pub cx: f64,
    /// Principal point y, pixels, pixel centres at integers.
    pub cy: f64,
    /// k1, k2, p1, p2, k3.
    pub distortion: [f64; 5],
    /// World → camera rotation (rows: image x, image y down, optical axis).
    pub rotation: [[f64; 3]; 3],
    /// World → camera translation, mm.
    pub translation: [f64; 3],
    /// Camera centre in the world, mm.
    pub centre_mm: [f64; 3],
}

impl CameraPose {
    /// This camera (built at turntable 0°) in OpenCV's convention.
    pub fn opencv(&self) -> OpenCvCamera {
        let rows =
            [self.right, -self.up, self.forward].map(|v| [v.x as f64, v.y as f64, v.z as f64]);
        let c = [
            self.origin.x as f64,
            self.origin.y as f64,
            self.origin.z as f64,
        ];
        let t = rows.map(|r| -(r[0] * c[0] + r[1] * c[1] + r[2] * c[2]));
        let f = f64::from(self.focal_px);
        OpenCvCamera {
            fx: f,
            fy: f,
            // The renderer samples pixel (x, y) at (x + 0.5, y + 0.5).
            cx: f64::from(self.principal_x) - 0.5,
            cy: f64::from(self.principal_y) - 0.5,
            distortion: [
                self.lens.k1,
                self.lens.k2,
                self.lens.p1,
                self.lens.p2,
                self.lens.k3,
            ],
            rotation: rows,
            translation: t,
            centre_mm: c,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam(az: f64, el: f64) -> CameraSpec {
        CameraSpec {
            id: "c".into(),
            backend: stagehand_devices::rig::Backend::Sim,
            port: None,
            width: 64,
            height: 48,
            fps: 10.0,
            bit_depth: 12,
            azimuth_deg: az,
            elevation_deg: el,
            distance_mm: 600.0,
            fov_deg: 11.0,
            min_exposure_s: 1e-5,
            max_exposure_s: 1.0,
            max_gain: 1.0,
            k1: 0.0,
            k2: 0.0,
            k3: 0.0,
            p1: 0.0,
            p2: 0.0,
            cx: 0.0,
            cy: 0.0,
        }
    }

    #[test]
    fn camera_looks_at_origin_with_plus_y_to_the_right() {
        let pose = CameraPose::new(&cam(0.0, 30.0), ToSample::new(0.0));
        let centre = pose.ray(32.0, 24.0);
        assert!((centre - (-pose.origin).normalize()).length() < 1e-5);
        let (x, y) = pose.project(Vec3A::new(0.0, 5.0, 0.0)).expect("in front");
        assert!(
            x > 32.0 && (y - 24.0).abs() < 1e-3,
            "+y appears right of centre: {x} {y}"
        );
        let (_, y) = pose.project(Vec3A::new(0.0, 0.0, 5.0)).expect("in front");
        assert!(y < 24.0, "+z appears above centre");
        // Looking straight down still gives a well-defined frame.
        let down = CameraPose::new(&cam(0.0, 90.0), ToSample::new(0.0));
        assert!(down.right.is_finite() && (down.right.length() - 1.0).abs() < 1e-5);
    }

    fn distorted(k1: f64) -> CameraSpec {
        CameraSpec {
            width: 640,
            height: 480,
            fov_deg: 40.0,
            k1,
            k2: 0.05,
            k3: -0.01,
            p1: 0.002,
            p2: -0.0015,
            cx: 6.5,
            cy: -4.25,
            ..cam(20.0, 35.0)
        }
    }

    #[test]
    fn project_inverts_ray_under_strong_distortion() {
        let spec = distorted(-0.2);
        stagehand_devices::lens::Intrinsics::of(&spec)
            .check()
            .expect("a valid lens");
        let pose = CameraPose::new(&spec, ToSample::new(30.0));
        let mut worst = 0.0f32;
        for j in 0..=24 {
            for i in 0..=32 {
                let (x, y) = (i as f32 * 20.0, j as f32 * 20.0);
                let d = pose.ray(x, y);
                let (px, py) = pose.project(pose.origin + d * 500.0).expect("in front");
                worst = worst.max((px - x).hypot(py - y));
            }
        }
        assert!(worst < 1.0e-3, "worst round trip {worst} px");
        // The principal point looks straight along the optical axis.
        let axis = pose.ray(320.0 + 6.5, 240.0 - 4.25);
        assert!((axis - pose.forward).length() < 1.0e-6, "{axis}");
    }

    #[test]
    fn zero_distortion_is_the_pinhole_bit_for_bit() {
        let spec = cam(15.0, 40.0);
        let pose = CameraPose::new(&spec, ToSample::new(12.0));
        let focal = (0.5 * spec.width as f64 / (0.5 * spec.fov_deg.to_radians()).tan()) as f32;
        assert_eq!(pose.focal_px.to_bits(), focal.to_bits());
        for j in 0..=12 {
            for i in 0..=16 {
                let (x, y) = (i as f32 * 4.0 + 0.37, j as f32 * 4.0 + 0.61);
                let dx = x - 0.5 * pose.width as f32;
                let dy = 0.5 * pose.height as f32 - y;
                let old = (pose.forward * focal + pose.right * dx + pose.up * dy).normalize();
                assert_eq!(
                    pose.ray(x, y).to_array().map(f32::to_bits),
                    old.to_array().map(f32::to_bits)
                );
                let p = pose.origin + old * 587.0;
                let v = p - pose.origin;
                let z = v.dot(pose.forward);
                let ox = 0.5 * pose.width as f32 + focal * v.dot(pose.right) / z;
                let oy = 0.5 * pose.height as f32 - focal * v.dot(pose.up) / z;
                let (px, py) = pose.project(p).expect("in front");
                assert_eq!((px.to_bits(), py.to_bits()), (ox.to_bits(), oy.to_bits()));
            }
        }
    }

    #[test]
    fn barrel_distortion_pulls_off_axis_points_inward() {
        let pinhole = CameraPose::new(&cam(0.0, 30.0), ToSample::new(0.0));
        let barrel = CameraPose::new(
            &CameraSpec {
                k1: -0.1,
                ..cam(0.0, 30.0)
            },
            ToSample::new(0.0),
        );
        let p = pinhole.origin + pinhole.ray(60.0, 44.0) * 600.0;
        let (x, y) = barrel.project(p).expect("in front");
        assert!(x < 60.0 && y < 44.0 && x > 32.0 && y > 24.0, "({x}, {y})");
    }

    #[test]
    fn turntable_moves_devices_the_other_way_in_the_sample_frame() {
        let p = ToSample::new(90.0).point(spherical(0.0, 0.0, 100.0));
        assert!((p - Vec3A::new(0.0, -100.0, 0.0)).length() < 1e-3, "{p}");
        let t = horizontal_tangent(0.0);
        let r = rotate_about(Vec3A::X, t, std::f32::consts::FRAC_PI_2);
        assert!((r - Vec3A::new(0.0, 0.0, -1.0)).length() < 1e-5, "{r}");
    }
}
