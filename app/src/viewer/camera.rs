//! The viewer's orbit camera.
//!
//! How it works: the camera looks at a `target` point from `distance` centimetres away, from the
//! direction given by `yaw` (azimuth around the world +z axis, the flat fabric's normal, measured
//! from +x toward +y) and `pitch` (elevation above the xy plane, kept inside ±89° so the view
//! never flips). Dragging changes yaw and pitch (orbit), panning moves the target in the image
//! plane, zooming scales the distance (or the film height of an orthographic camera), and
//! fitting centres the target on a bounding box and backs off until its bounding sphere fills
//! the view. [`OrbitCamera::section`] turns it back into the scene's `[camera]` section, which is
//! what the renderer takes; `up` is always +z.

use glam::DVec3;
use twill_precompute::scene::{CameraSection, ProjectionKind};

/// Pitch limit in degrees (the view direction never becomes parallel to `up`).
pub const MAX_PITCH_DEG: f64 = 89.0;
/// Closest and farthest eye distance in cm.
pub const DISTANCE_RANGE_CM: (f64, f64) = (1e-3, 1e3);
/// Degrees of orbit per point of mouse drag.
pub const ORBIT_DEG_PER_POINT: f64 = 0.35;

/// An orbiting camera around a target point (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbitCamera {
    pub target: DVec3,
    /// Eye-to-target distance in cm.
    pub distance: f64,
    /// Azimuth of the eye around +z, degrees from +x toward +y.
    pub yaw_deg: f64,
    /// Elevation of the eye above the xy plane, degrees.
    pub pitch_deg: f64,
    pub projection: ProjectionKind,
    /// Full vertical field of view (perspective).
    pub fov_y_deg: f64,
    /// Film height in cm (orthographic).
    pub height_cm: f64,
}

impl OrbitCamera {
    /// The orbit camera that sees what a scene's `[camera]` sees (up becomes +z).
    #[must_use]
    pub fn from_section(section: &CameraSection) -> Self {
        let target = DVec3::from(section.target);
        let offset = DVec3::from(section.eye) - target;
        let distance = offset.length().clamp(DISTANCE_RANGE_CM.0, DISTANCE_RANGE_CM.1);
        let horizontal = offset.truncate().length();
        let yaw_deg = if horizontal > 1e-12 { offset.y.atan2(offset.x).to_degrees() } else { -90.0 };
        let pitch_deg = offset.z.atan2(horizontal).to_degrees().clamp(-MAX_PITCH_DEG, MAX_PITCH_DEG);
        Self {
            target,
            distance,
            yaw_deg,
            pitch_deg,
            projection: section.projection,
            fov_y_deg: section.fov_y_deg,
            height_cm: section.height_cm,
        }
    }

    /// Unit vector from the target toward the eye.
    #[must_use]
    pub fn eye_direction(&self) -> DVec3 {
        let (yaw, pitch) = (self.yaw_deg.to_radians(), self.pitch_deg.to_radians());
        DVec3::new(pitch.cos() * yaw.cos(), pitch.cos() * yaw.sin(), pitch.sin())
    }

    #[must_use]
    pub fn eye(&self) -> DVec3 {
        self.target + self.distance * self.eye_direction()
    }

    /// (right, up) unit vectors of the image plane.
    #[must_use]
    pub fn image_axes(&self) -> (DVec3, DVec3) {
        let forward = -self.eye_direction();
        let right = forward.cross(DVec3::Z).normalize();
        (right, right.cross(forward))
    }

    /// The scene's `[camera]` section for this view.
    #[must_use]
    pub fn section(&self) -> CameraSection {
        CameraSection {
            projection: self.projection,
            eye: self.eye().to_array(),
            target: self.target.to_array(),
            up: [0.0, 0.0, 1.0],
            fov_y_deg: self.fov_y_deg,
            height_cm: self.height_cm,
        }
    }

    /// Orbits by a mouse drag of (`dx`, `dy`) points: dragging right turns the fabric right,
    /// dragging down tilts the camera up over it.
    pub fn orbit_by_drag(&mut self, dx: f64, dy: f64) {
        self.orbit(-dx * ORBIT_DEG_PER_POINT, dy * ORBIT_DEG_PER_POINT);
    }

    /// Turns the eye around the target by `dyaw` and `dpitch` degrees.
    pub fn orbit(&mut self, dyaw_deg: f64, dpitch_deg: f64) {
        self.yaw_deg = (self.yaw_deg + dyaw_deg).rem_euclid(360.0);
        if self.yaw_deg > 180.0 {
            self.yaw_deg -= 360.0;
        }
        self.pitch_deg = (self.pitch_deg + dpitch_deg).clamp(-MAX_PITCH_DEG, MAX_PITCH_DEG);
    }

    /// Height in cm of the view at the target's distance.
    #[must_use]
    pub fn view_height_cm(&self) -> f64 {
        match self.projection {
            ProjectionKind::Perspective => 2.0 * self.distance * (0.5 * self.fov_y_deg.to_radians()).tan(),
            ProjectionKind::Orthographic => self.height_cm,
        }
    }

    /// Moves the target so that the fabric follows a drag of (`dx`, `dy`) points in a view
    /// `view_height` points tall.
    pub fn pan_by_drag(&mut self, dx: f64, dy: f64, view_height: f64) {
        let cm_per_point = self.view_height_cm() / view_height.max(1.0);
        let (right, up) = self.image_axes();
        self.target += cm_per_point * (-dx * right + dy * up);
    }

    /// Zooms in (`factor` < 1) or out (`factor` > 1).
    pub fn zoom(&mut self, factor: f64) {
        let factor = factor.clamp(0.01, 100.0);
        match self.projection {
            ProjectionKind::Perspective => {
                self.distance = (self.distance * factor).clamp(DISTANCE_RANGE_CM.0, DISTANCE_RANGE_CM.1);
            }
            ProjectionKind::Orthographic => {
                self.height_cm = (self.height_cm * factor).clamp(1e-4, 1e4);
            }
        }
    }

    /// Centres the view on the box `lo`..`hi` and frames its bounding sphere in a view of
    /// aspect `aspect` (width / height), keeping the direction of view.
    pub fn fit(&mut self, lo: DVec3, hi: DVec3, aspect: f64) {
        let radius = (0.5 * (hi - lo).length()).max(1e-4) * 1.05;
        self.target = 0.5 * (lo + hi);
        let aspect = aspect.max(1e-3);
        match self.projection {
            ProjectionKind::Perspective => {
                let half_v = 0.5 * self.fov_y_deg.to_radians();
                let half_h = (half_v.tan() * aspect).atan();
                let half = half_v.min(half_h);
                self.distance = (radius / half.sin()).clamp(DISTANCE_RANGE_CM.0, DISTANCE_RANGE_CM.1);
            }
            ProjectionKind::Orthographic => {
                self.height_cm = 2.0 * radius / aspect.min(1.0);
                self.distance = (4.0 * radius).clamp(DISTANCE_RANGE_CM.0, DISTANCE_RANGE_CM.1);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn default_section() -> CameraSection {
        twill_precompute::scene::SceneFile::default_scene().camera
    }

    #[test]
    fn a_scene_camera_round_trips_through_the_orbit_camera() {
        let section = default_section();
        let camera = OrbitCamera::from_section(&section);
        let back = camera.section();
        for i in 0..3 {
            assert!((back.eye[i] - section.eye[i]).abs() < 1e-9, "{back:?} vs {section:?}");
            assert!((back.target[i] - section.target[i]).abs() < 1e-12);
        }
        assert!((camera.yaw_deg + 90.0).abs() < 1e-9);
    }

    #[test]
    fn orbiting_keeps_the_distance_and_clamps_the_pitch() {
        let mut camera = OrbitCamera::from_section(&default_section());
        let d = (camera.eye() - camera.target).length();
        camera.orbit(400.0, 500.0);
        assert!(((camera.eye() - camera.target).length() - d).abs() < 1e-9);
        assert!((camera.pitch_deg - MAX_PITCH_DEG).abs() < 1e-12);
        assert!((-180.0..=180.0).contains(&camera.yaw_deg));
    }

    #[test]
    fn panning_moves_the_target_in_the_image_plane() {
        let mut camera = OrbitCamera::from_section(&default_section());
        let before = camera.target;
        camera.pan_by_drag(100.0, 0.0, 500.0);
        let moved = camera.target - before;
        let (right, up) = camera.image_axes();
        assert!(moved.dot(right) < 0.0, "dragging right moves the target left");
        assert!(moved.dot(up).abs() < 1e-12);
        assert!((moved.length() - camera.view_height_cm() / 5.0).abs() < 1e-9);
    }

    #[test]
    fn fitting_frames_the_bounding_sphere() {
        let mut camera = OrbitCamera::from_section(&default_section());
        let (lo, hi) = (DVec3::new(-1.0, -1.0, -0.02), DVec3::new(1.0, 1.0, 0.02));
        camera.fit(lo, hi, 2.0);
        assert!(camera.target.length() < 1e-12);
        let radius = 0.5 * (hi - lo).length() * 1.05;
        let half = 0.5 * camera.fov_y_deg.to_radians();
        assert!((camera.distance * half.sin() - radius).abs() < 1e-9);
        // Taller than wide: the horizontal angle limits.
        camera.fit(lo, hi, 0.5);
        assert!(camera.distance * half.sin() > radius * 1.5);
    }
}
