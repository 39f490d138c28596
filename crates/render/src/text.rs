//! Labels in a built-in 5 × 7 bitmap font: the digits and the few signs that time stamps and
//! strain percentages need (`t = 1.23 s`, `-10%`, `+1e-4%`). No font file and no text crate:
//! the same pixels on every machine.

/// Glyph columns.
pub const GLYPH_WIDTH: usize = 5;
/// Glyph rows.
pub const GLYPH_HEIGHT: usize = 7;
/// From one glyph's left edge to the next's, pixels at scale 1 (a column of space between).
pub const ADVANCE: usize = GLYPH_WIDTH + 1;

/// The rows of `c`, top first, bit 4 the leftmost column; a character without a glyph is a
/// space.
fn glyph(c: char) -> [u8; GLYPH_HEIGHT] {
    match c {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '+' => [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00],
        '=' => [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        't' => [0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06],
        's' => [0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E],
        'e' => [0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E],
        _ => [0; GLYPH_HEIGHT],
    }
}

/// The width of `text` drawn at `scale`, pixels (no space after the last glyph).
pub fn width(text: &str, scale: usize) -> usize {
    (text.chars().count() * ADVANCE).saturating_sub(1) * scale
}

/// Calls `put(x, y)` for every pixel of `text` drawn at `scale` (each font pixel a
/// `scale` × `scale` square) with its top-left corner at (`x0`, `y0`).
pub fn draw(text: &str, x0: usize, y0: usize, scale: usize, mut put: impl FnMut(usize, usize)) {
    for (k, c) in text.chars().enumerate() {
        let left = x0 + k * ADVANCE * scale;
        for (row, bits) in glyph(c).into_iter().enumerate() {
            for col in 0..GLYPH_WIDTH {
                if bits & (0x10 >> col) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        put(left + col * scale + dx, y0 + row * scale + dy);
                    }
                }
            }
        }
    }
}

/// The scale of labels on a picture `height` pixels high: font pixels of one picture pixel up
/// to 239 rows, two from 240 (a 480-row picture's labels are 14 rows high).
pub fn scale_for(height: u32) -> usize {
    (height as usize / 240).max(1)
}

/// A strain as a percentage for the colour bar, with its sign: `-10%`, `+5%`, `+0.25%`,
/// `+1e-4%` below a thousandth of a percent.
pub fn percent(strain: f64) -> String {
    let p = 100.0 * strain;
    let sign = if p < 0.0 { "-" } else { "+" };
    let p = p.abs();
    let digits = if p >= 1e-3 {
        let fixed = format!("{p:.3}");
        fixed.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        format!("{p:.0e}")
    };
    format!("{sign}{digits}%")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glyphs_are_drawn_at_their_place_and_scale() {
        let mut lit = Vec::new();
        draw("-", 10, 20, 2, |x, y| lit.push((x, y)));
        // The minus is row 3, columns 0 to 4: at scale 2, rows 26 and 27, columns 10 to 19.
        let expected: Vec<(usize, usize)> = (26..28)
            .flat_map(|y| (10..20).map(move |x| (x, y)))
            .collect();
        lit.sort_by_key(|&(x, y)| (y, x));
        assert_eq!(lit, expected);
        assert_eq!(width("t = 1.23 s", 1), 59);
        let mut n = 0;
        draw(" ?", 0, 0, 1, |_, _| n += 1);
        assert_eq!(n, 0, "no glyph: a space");
    }

    #[test]
    fn strains_read_as_signed_percentages() {
        assert_eq!(percent(-0.1), "-10%");
        assert_eq!(percent(0.05), "+5%");
        assert_eq!(percent(0.0025), "+0.25%");
        assert_eq!(percent(1e-5), "+0.001%");
        assert_eq!(percent(1e-6), "+1e-4%");
        assert_eq!(scale_for(120), 1);
        assert_eq!(scale_for(480), 2);
    }
}
