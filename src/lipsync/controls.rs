//! Articulatory controls (lip-sync v4): what the network says a mouth does, and what every head
//! is driven by. Aperture and width are what a face tracker sees (eye widths, relative to the
//! speaker's own rest face), so real lips can teach them; the others are activations.

/// One frame's mouth, as independent controls.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Controls {
    /// Inner-lip gap (MediaPipe 13-14) above the rest gap, in eye widths (33-263).
    pub aperture: f32,
    /// Mouth-corner distance (61-291) above the rest width, in eye widths: + spread, - narrowed.
    pub width: f32,
    /// Jaw opening, 0 (closed) to 1 (fully open).
    pub jaw: f32,
    /// Lips rounded and pushed forward (/u/, /w/), 0 to 1.
    pub rounding: f32,
    /// Lips pressed together (/p b m/), 0 to 1.
    pub closure: f32,
    /// Lower lip drawn up to the upper teeth (/f v/), 0 to 1.
    pub lower_lip_tuck: f32,
}

pub const CONTROL_COUNT: usize = 6;

/// The controls' names, in [`Controls::to_array`] order.
pub const CONTROL_NAMES: [&str; CONTROL_COUNT] = [
    "aperture",
    "width",
    "jaw",
    "rounding",
    "closure",
    "lower_lip_tuck",
];

impl Controls {
    pub fn to_array(&self) -> [f32; CONTROL_COUNT] {
        [
            self.aperture,
            self.width,
            self.jaw,
            self.rounding,
            self.closure,
            self.lower_lip_tuck,
        ]
    }

    pub fn from_array(values: [f32; CONTROL_COUNT]) -> Self {
        let [aperture, width, jaw, rounding, closure, lower_lip_tuck] = values;
        Self {
            aperture,
            width,
            jaw,
            rounding,
            closure,
            lower_lip_tuck,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn array_order_round_trips_and_matches_the_names() {
        let c = Controls {
            aperture: 0.1,
            width: -0.02,
            jaw: 0.4,
            rounding: 0.7,
            closure: 0.0,
            lower_lip_tuck: 0.3,
        };
        assert_eq!(Controls::from_array(c.to_array()), c);
        assert_eq!(CONTROL_NAMES[1], "width");
        assert_eq!(c.to_array()[1], -0.02);
    }
}
