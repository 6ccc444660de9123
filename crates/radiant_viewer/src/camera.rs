//! Orbit and fly camera: left drag orbits the target, right drag looks around, the wheel
//! zooms, WASD (and Q/E) fly. Pure maths over `glam`; the window feeds it events.

use glam::DVec3;

/// A camera that orbits a target point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrbitCamera {
    /// The point orbited and looked at.
    pub target: DVec3,
    /// Distance from the target.
    pub distance: f64,
    /// Rotation about the world's up axis, radians.
    pub yaw: f64,
    /// Elevation, radians, within ±89°.
    pub pitch: f64,
    /// The world's up axis (unit).
    pub up: DVec3,
}

const PITCH_LIMIT: f64 = 89.0_f64.to_radians();

/// An orthonormal frame (right, forward-in-plane, up) around `up`.
fn basis(up: DVec3) -> (DVec3, DVec3) {
    let helper = if up.x.abs() < 0.9 { DVec3::X } else { DVec3::Z };
    let a = up.cross(helper).normalize();
    let b = a.cross(up).normalize();
    (a, b)
}

impl OrbitCamera {
    /// Looks from `position` along `forward`, orbiting the point `distance` ahead. Degenerate
    /// inputs (zero or non-finite vectors) fall back to looking down −z at the origin.
    pub fn looking(position: DVec3, forward: DVec3, up: DVec3, distance: f64) -> Self {
        let up = up.try_normalize().unwrap_or(DVec3::Y);
        let forward = forward.try_normalize().unwrap_or(-DVec3::Z);
        let distance = if distance.is_finite() && distance > 1e-6 {
            distance
        } else {
            1.0
        };
        let (a, b) = basis(up);
        let dir = -forward; // from target to eye
        let pitch = dir
            .dot(up)
            .clamp(-1.0, 1.0)
            .asin()
            .clamp(-PITCH_LIMIT, PITCH_LIMIT);
        let yaw = dir.dot(a).atan2(dir.dot(b));
        let position = if position.is_finite() {
            position
        } else {
            DVec3::ZERO
        };
        Self {
            target: position + forward * distance,
            distance,
            yaw,
            pitch,
            up,
        }
    }

    /// Unit vector from the target to the eye.
    fn offset_dir(&self) -> DVec3 {
        let (a, b) = basis(self.up);
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        (a * sy + b * cy) * cp + self.up * sp
    }

    /// The eye position.
    pub fn position(&self) -> DVec3 {
        self.target + self.offset_dir() * self.distance
    }

    /// Unit view direction.
    pub fn forward(&self) -> DVec3 {
        -self.offset_dir()
    }

    /// Unit vector to the right of the view.
    pub fn right(&self) -> DVec3 {
        self.forward().cross(self.up).normalize_or(DVec3::X)
    }

    /// Orbits by a mouse drag of `(dx, dy)` pixels.
    pub fn orbit(&mut self, dx: f64, dy: f64) {
        self.yaw -= dx * 0.005;
        self.pitch = (self.pitch + dy * 0.005).clamp(-PITCH_LIMIT, PITCH_LIMIT);
    }

    /// Turns the view in place (the eye stays, the target moves) by a drag of `(dx, dy)`.
    pub fn look(&mut self, dx: f64, dy: f64) {
        let eye = self.position();
        self.orbit(-dx, -dy);
        self.target = eye - self.offset_dir() * self.distance;
    }

    /// Zooms by `steps` wheel notches (positive: closer).
    pub fn zoom(&mut self, steps: f64) {
        self.distance = (self.distance * 0.9f64.powf(steps)).clamp(1e-3, 1e7);
    }

    /// Flies by `(right, up, forward)` in units of the orbit distance.
    pub fn fly(&mut self, right: f64, up: f64, forward: f64) {
        let step = self.right() * right + self.up * up + self.forward() * forward;
        self.target += step * self.distance;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: DVec3, b: DVec3) -> bool {
        (a - b).length() < 1e-9
    }

    #[test]
    fn looking_reproduces_the_camera() {
        let pos = DVec3::new(0.278, 0.273, -0.8);
        let fwd = DVec3::Z;
        let cam = OrbitCamera::looking(pos, fwd, DVec3::Y, 1.0);
        assert!(close(cam.position(), pos), "{:?}", cam.position());
        assert!(close(cam.forward(), fwd));
        assert!(close(cam.target, pos + fwd));
    }

    #[test]
    fn orbit_keeps_distance_and_target_and_clamps_pitch() {
        let mut cam = OrbitCamera::looking(DVec3::new(0.0, 0.0, 5.0), -DVec3::Z, DVec3::Y, 5.0);
        let target = cam.target;
        cam.orbit(300.0, 120.0);
        assert!(close(cam.target, target));
        assert!(((cam.position() - target).length() - 5.0).abs() < 1e-9);
        cam.orbit(0.0, 1e6);
        assert!(cam.pitch <= PITCH_LIMIT && cam.forward().is_finite());
    }

    #[test]
    fn look_keeps_the_eye_and_fly_moves_both() {
        let mut cam = OrbitCamera::looking(DVec3::new(1.0, 2.0, 3.0), DVec3::X, DVec3::Y, 2.0);
        let eye = cam.position();
        cam.look(50.0, -20.0);
        assert!(close(cam.position(), eye));
        let before = cam.position();
        cam.fly(0.0, 0.0, 0.5);
        assert!(close(cam.position() - before, cam.forward()));
    }

    #[test]
    fn degenerate_input_gives_a_finite_camera() {
        let cam = OrbitCamera::looking(DVec3::NAN, DVec3::ZERO, DVec3::ZERO, f64::NAN);
        assert!(cam.position().is_finite() && cam.forward().is_finite());
        let mut cam = cam;
        cam.zoom(1e9);
        assert!(cam.distance >= 1e-3);
    }
}
