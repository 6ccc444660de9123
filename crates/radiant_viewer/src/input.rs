//! Mouse and keyboard: what is held, and what each event does to the camera.

use std::collections::HashSet;

use glam::DVec3;

use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::keyboard::{KeyCode, PhysicalKey};

use crate::camera::OrbitCamera;

/// What an event asks of the viewer beyond moving the camera.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Action {
    /// Show or hide the inspector (`Tab`, `F1`).
    ToggleInspector,
    /// Close the window (`Escape`).
    Close,
}

/// Buttons and keys held, and the cursor.
#[derive(Default)]
pub(crate) struct Input {
    drag: Option<MouseButton>,
    cursor: Option<(f64, f64)>,
    keys: HashSet<KeyCode>,
}

impl Input {
    /// Applies `event` to the camera; `consumed` when the inspector took it.
    pub(crate) fn on_event(
        &mut self,
        event: &WindowEvent,
        consumed: bool,
        camera: &mut OrbitCamera,
    ) -> Option<Action> {
        match event {
            WindowEvent::Focused(false) => {
                // Releases that happen elsewhere never arrive: forget what is held.
                self.keys.clear();
                self.drag = None;
            }
            WindowEvent::KeyboardInput { event, .. } => {
                let PhysicalKey::Code(code) = event.physical_key else {
                    return None;
                };
                match event.state {
                    ElementState::Pressed if consumed => {}
                    ElementState::Pressed => {
                        if code == KeyCode::Escape {
                            return Some(Action::Close);
                        }
                        self.keys.insert(code);
                        if matches!(code, KeyCode::Tab | KeyCode::F1) && !event.repeat {
                            return Some(Action::ToggleInspector);
                        }
                    }
                    ElementState::Released => {
                        self.keys.remove(&code);
                    }
                }
            }
            WindowEvent::MouseInput { state, button, .. } => {
                if *state == ElementState::Pressed && !consumed {
                    self.drag = Some(*button);
                } else if *state == ElementState::Released {
                    self.drag = None;
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                let p = (position.x, position.y);
                if let (Some(button), Some(last)) = (self.drag, self.cursor) {
                    let (dx, dy) = (p.0 - last.0, p.1 - last.1);
                    match button {
                        MouseButton::Left => camera.orbit(dx, dy),
                        MouseButton::Right => camera.look(dx, dy),
                        _ => {}
                    }
                }
                self.cursor = Some(p);
            }
            WindowEvent::MouseWheel { delta, .. } if !consumed => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => f64::from(*y),
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                camera.zoom(steps);
            }
            _ => {}
        }
        None
    }

    /// How far the dynamic meshes move in `dt` seconds with the arrow keys (x, z) and Page
    /// Up/Down (y) held, at `speed` scene units a second; `None` when none is held.
    pub(crate) fn nudge(&self, dt: f64, speed: f64) -> Option<DVec3> {
        let k = |code: KeyCode| f64::from(u8::from(self.keys.contains(&code)));
        let d = DVec3::new(
            k(KeyCode::ArrowRight) - k(KeyCode::ArrowLeft),
            k(KeyCode::PageUp) - k(KeyCode::PageDown),
            k(KeyCode::ArrowDown) - k(KeyCode::ArrowUp),
        );
        (d != DVec3::ZERO).then_some(d * speed * dt)
    }

    /// Flies the camera for `dt` seconds with WASD and Q/E held.
    pub(crate) fn fly(&self, dt: f64, camera: &mut OrbitCamera) {
        let k = |code: KeyCode| f64::from(u8::from(self.keys.contains(&code)));
        let right = k(KeyCode::KeyD) - k(KeyCode::KeyA);
        let up = k(KeyCode::KeyE) - k(KeyCode::KeyQ);
        let forward = k(KeyCode::KeyW) - k(KeyCode::KeyS);
        if right != 0.0 || up != 0.0 || forward != 0.0 {
            let speed = 0.8 * dt;
            camera.fly(right * speed, up * speed, forward * speed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arrows_and_page_keys_move_the_dynamic_meshes() {
        let mut input = Input::default();
        assert_eq!(input.nudge(0.5, 2.0), None);
        input.keys.insert(KeyCode::ArrowRight);
        input.keys.insert(KeyCode::PageUp);
        input.keys.insert(KeyCode::ArrowUp);
        assert_eq!(input.nudge(0.5, 2.0), Some(DVec3::new(1.0, 1.0, -1.0)));
        input.keys.insert(KeyCode::ArrowLeft);
        input.keys.insert(KeyCode::PageDown);
        input.keys.insert(KeyCode::ArrowDown);
        assert_eq!(input.nudge(0.5, 2.0), None, "opposite keys cancel");
    }
}
