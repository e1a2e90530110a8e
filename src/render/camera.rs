//! Cameras that frame a head's face or, for lipreading, its mouth.

use glam::{Mat4, Vec3};

use super::head::FaceFrame;

/// What the camera shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Framing {
    /// The whole face, forehead to chin.
    #[default]
    Face,
    /// A close-up of the lips, teeth and tongue.
    Mouth,
}

/// A perspective camera. glTF heads face +Z, so the default eye is on the +Z side.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    /// Vertical field of view in radians.
    pub fov_y: f32,
    pub near: f32,
    pub far: f32,
}

impl Camera {
    /// Frames a head from the front.
    pub fn framing(frame: &FaceFrame, framing: Framing) -> Self {
        Self::framing_yaw(frame, framing, 0.0)
    }

    /// Frames a head from an angle `yaw` (radians, positive turns the view to the head's left).
    pub fn framing_yaw(frame: &FaceFrame, framing: Framing, yaw: f32) -> Self {
        let fov_y = 25f32.to_radians();
        let w = frame.mouth_width.max(1e-4);
        // Heights of the visible region, in mouth widths.
        let (target, visible) = match framing {
            Framing::Face => {
                let head_h = (frame.head_max.y - frame.head_min.y).max(w * 2.0);
                let visible = head_h.min(w * 7.4);
                (frame.mouth + Vec3::new(0.0, 0.225 * visible, 0.0), visible)
            }
            Framing::Mouth => (frame.mouth, w * 1.75),
        };
        let distance = 0.5 * visible / (0.5 * fov_y).tan();
        let dir = Vec3::new(yaw.sin(), 0.0, yaw.cos());
        let pivot = Vec3::new(target.x, target.y, frame.mouth.z - 2.0 * w);
        let eye = pivot + dir * (distance + 2.0 * w);
        Self {
            eye,
            target: pivot + dir * 2.0 * w,
            up: Vec3::Y,
            fov_y,
            near: (distance * 0.1).max(1e-4),
            far: distance * 10.0 + 10.0 * w,
        }
    }

    /// Pixels a metre spans at the target's distance in a viewport `viewport_height` pixels
    /// high.
    pub fn pixels_per_metre(&self, viewport_height: u32) -> f32 {
        let distance = (self.eye - self.target).length();
        viewport_height as f32 / (2.0 * distance * (0.5 * self.fov_y).tan())
    }

    pub fn view(&self) -> Mat4 {
        glam::camera::rh::view::look_at_mat4(self.eye, self.target, self.up)
    }

    /// Projection (wgpu depth range 0..1) times view.
    pub fn view_proj(&self, aspect: f32) -> Mat4 {
        let aspect = if aspect.is_finite() && aspect > 0.0 {
            aspect
        } else {
            1.0
        };
        glam::camera::rh::proj::directx::perspective(self.fov_y, aspect, self.near, self.far)
            * self.view()
    }
}
