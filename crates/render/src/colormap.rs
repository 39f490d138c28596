//! The strain colormap: a diverging blue–grey–red ramp.
//!
//! A spring's strain is ε = (|x_a − x_b| − r)/r (r: rest length). Its colour is the linear
//! interpolation in RGB from [`COMPRESSED`] at ε = −s through [`NEUTRAL`] at ε = 0 to
//! [`STRETCHED`] at ε = +s, where s is the strain range ([`crate::RenderOptions::strain_range`]);
//! strains beyond ±s take the end colours.

/// The colour of a spring compressed by the whole strain range or more (blue).
pub const COMPRESSED: [u8; 3] = [40, 70, 210];
/// The colour of a spring at its rest length: a mid grey, which reads on light ground and sky
/// alike (a white middle, usual on white paper, vanishes against them).
pub const NEUTRAL: [u8; 3] = [120, 120, 120];
/// The colour of a spring stretched by the whole strain range or more (red).
pub const STRETCHED: [u8; 3] = [210, 30, 35];

/// The colour of strain `strain` on a ramp spanning ±`range` (`range` > 0; a non-finite
/// strain is drawn as fully stretched).
pub fn strain_color(strain: f64, range: f64) -> [u8; 3] {
    let u = if strain.is_nan() {
        1.0
    } else {
        (strain / range).clamp(-1.0, 1.0)
    };
    let (from, to, t) = if u < 0.0 {
        (NEUTRAL, COMPRESSED, -u)
    } else {
        (NEUTRAL, STRETCHED, u)
    };
    std::array::from_fn(|k| {
        (f64::from(from[k]) + (f64::from(to[k]) - f64::from(from[k])) * t).round() as u8
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn end_points_and_middle() {
        assert_eq!(strain_color(-0.1, 0.1), COMPRESSED);
        assert_eq!(strain_color(0.1, 0.1), STRETCHED);
        assert_eq!(strain_color(0.0, 0.1), NEUTRAL);
        // Beyond the range: clamped to the ends.
        assert_eq!(strain_color(-5.0, 0.1), COMPRESSED);
        assert_eq!(strain_color(5.0, 0.1), STRETCHED);
        assert_eq!(strain_color(f64::INFINITY, 0.1), STRETCHED);
        assert_eq!(strain_color(f64::NAN, 0.1), STRETCHED);
        // Halfway to stretched: the mean of neutral and red, rounded.
        assert_eq!(strain_color(0.05, 0.1), [165, 75, 78]);
        // Compression is blue-dominated, stretching red-dominated.
        let [r, _, b] = strain_color(-0.03, 0.1);
        assert!(b > r);
        let [r, _, b] = strain_color(0.03, 0.1);
        assert!(r > b);
    }
}
