//! Pinhole (perspective) and orthographic cameras.
//!
//! A camera maps a point on the film, in pixel units with (0, 0) at the top-left corner, to a
//! world-space ray. The camera looks from `eye` toward `target`; `up` fixes the roll. The
//! perspective camera's `fov_y_deg` is the full vertical field of view; the orthographic
//! camera's `height_cm` is the film's height in world units.

use glam::DVec3;

use crate::params::{ParamError, check_positive, check_range};

/// Projection of a camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Projection {
    Perspective { fov_y_deg: f64 },
    Orthographic { height_cm: f64 },
}

/// A camera placed in the world, ready to generate rays for a film of `width` x `height`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    eye: DVec3,
    /// Unit vectors of the camera frame: right, up (on the film), forward (viewing direction).
    right: DVec3,
    up: DVec3,
    forward: DVec3,
    projection: Projection,
    width: usize,
    height: usize,
}

impl Camera {
    pub fn new(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        projection: Projection,
        width: usize,
        height: usize,
    ) -> Result<Self, ParamError> {
        for (name, v) in [("camera.eye", eye), ("camera.target", target), ("camera.up", up)] {
            if !v.is_finite() {
                return Err(ParamError::new(
                    name,
                    format!("[{}, {}, {}]", v.x, v.y, v.z),
                    "finite coordinates (no NaN or infinity)",
                ));
            }
        }
        let forward = (target - eye).normalize_or_zero();
        if forward == DVec3::ZERO || !forward.is_finite() {
            return Err(ParamError::new(
                "camera.target",
                format!("{target}"),
                "a point different from camera.eye",
            ));
        }
        let right = forward.cross(up).normalize_or_zero();
        if right == DVec3::ZERO || !right.is_finite() {
            return Err(ParamError::new(
                "camera.up",
                format!("{up}"),
                "a direction not parallel to the view direction",
            ));
        }
        match projection {
            Projection::Perspective { fov_y_deg } => {
                check_range("camera.fov_y_deg", fov_y_deg, 0.01, 179.0)?;
            }
            Projection::Orthographic { height_cm } => {
                check_positive("camera.height_cm", height_cm)?;
            }
        }
        if width == 0 || height == 0 {
            return Err(ParamError::new("resolution", format!("{width}x{height}"), "at least 1x1"));
        }
        Ok(Self { eye, right, up: right.cross(forward), forward, projection, width, height })
    }

    /// The ray through film point `(px, py)` (pixel units, y down): `(origin, unit direction)`.
    #[must_use]
    pub fn ray(&self, px: f64, py: f64) -> (DVec3, DVec3) {
        let aspect = self.width as f64 / self.height as f64;
        // Film coordinates in [-1, 1] vertically, [-aspect, aspect] horizontally.
        let sx = (2.0 * px / self.width as f64 - 1.0) * aspect;
        let sy = 1.0 - 2.0 * py / self.height as f64;
        match self.projection {
            Projection::Perspective { fov_y_deg } => {
                let half = (0.5 * fov_y_deg.to_radians()).tan();
                let dir = (self.forward + half * (sx * self.right + sy * self.up)).normalize();
                (self.eye, dir)
            }
            Projection::Orthographic { height_cm } => {
                let half = 0.5 * height_cm;
                (self.eye + half * (sx * self.right + sy * self.up), self.forward)
            }
        }
    }

    #[must_use]
    pub fn width(&self) -> usize {
        self.width
    }

    #[must_use]
    pub fn height(&self) -> usize {
        self.height
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_points_are_named_as_themselves() {
        let p = Projection::Perspective { fov_y_deg: 30.0 };
        let (eye, target, up) = (DVec3::new(0.0, -1.0, 1.0), DVec3::ZERO, DVec3::Z);
        for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let bad = DVec3::new(0.0, x, 1.0);
            for (name, e, t, u) in [
                ("camera.eye", bad, target, up),
                ("camera.target", eye, bad, up),
                ("camera.up", eye, target, bad),
            ] {
                let err = Camera::new(e, t, u, p, 4, 4).unwrap_err();
                assert_eq!(err.name, name, "{err}");
                assert!(err.to_string().contains("finite"), "{err}");
            }
        }
    }

    #[test]
    fn centre_ray_looks_at_the_target_and_corners_span_the_field_of_view() {
        let cam = Camera::new(
            DVec3::new(0.0, 0.0, 10.0),
            DVec3::ZERO,
            DVec3::Y,
            Projection::Perspective { fov_y_deg: 90.0 },
            200,
            100,
        )
        .unwrap();
        let (o, d) = cam.ray(100.0, 50.0);
        assert_eq!(o, DVec3::new(0.0, 0.0, 10.0));
        assert!((d - DVec3::NEG_Z).length() < 1e-12);
        // Top edge at 45 degrees above the axis; y down on the film means +y in the world here.
        let (_, top) = cam.ray(100.0, 0.0);
        assert!((top.angle_between(DVec3::NEG_Z).to_degrees() - 45.0).abs() < 1e-9);
        assert!(top.y > 0.0);
        let (_, right) = cam.ray(200.0, 50.0);
        assert!(right.x > 0.0, "film x grows to the camera's right");
    }

    #[test]
    fn orthographic_rays_are_parallel_and_cover_the_film_height() {
        let cam = Camera::new(
            DVec3::new(0.0, 0.0, 5.0),
            DVec3::ZERO,
            DVec3::Y,
            Projection::Orthographic { height_cm: 2.0 },
            10,
            10,
        )
        .unwrap();
        let (o0, d0) = cam.ray(5.0, 0.0);
        let (o1, d1) = cam.ray(5.0, 10.0);
        assert_eq!(d0, d1);
        assert!(((o0 - o1).length() - 2.0).abs() < 1e-12);
    }

    #[test]
    fn degenerate_cameras_are_rejected() {
        let ortho = Projection::Orthographic { height_cm: 1.0 };
        assert!(Camera::new(DVec3::ZERO, DVec3::ZERO, DVec3::Y, ortho, 4, 4).is_err());
        assert!(Camera::new(DVec3::Z, DVec3::ZERO, DVec3::Z, ortho, 4, 4).is_err());
        let bad_fov = Projection::Perspective { fov_y_deg: 180.0 };
        assert!(Camera::new(DVec3::Z, DVec3::ZERO, DVec3::Y, bad_fov, 4, 4).is_err());
    }
}
