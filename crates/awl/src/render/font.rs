//! A tiny embedded 5x7 bitmap font for legend labels: digits, `.`, `-`, `+`, space and the
//! lower-case letters of units and view names (`m`, `d`, `e`, `g`). Other characters draw as blanks.

use crate::image::ColorImage;

/// Glyph width, pixels (at scale 1), without the 1-pixel spacing.
pub const GLYPH_W: u32 = 5;
/// Glyph height, pixels (at scale 1).
pub const GLYPH_H: u32 = 7;

/// Rows top to bottom; bit 4 is the leftmost column.
fn glyph(c: char) -> [u8; 7] {
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
        'm' => [0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11],
        'd' => [0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F],
        'e' => [0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E],
        'g' => [0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x0E],
        _ => [0; 7],
    }
}

/// Width in pixels of `text` drawn at `scale` (glyphs separated by one scaled pixel).
pub fn text_width(text: &str, scale: u32) -> u32 {
    let n = text.chars().count() as u32;
    if n == 0 { 0 } else { (n * (GLYPH_W + 1) - 1) * scale }
}

/// Draws `text` with its top-left corner at `(x, y)`, each font pixel a `scale` x `scale` block;
/// pixels outside the image are clipped.
pub fn draw_text(image: &mut ColorImage, x: i64, y: i64, text: &str, scale: u32, color: [u8; 3]) {
    let s = i64::from(scale.max(1));
    for (k, c) in text.chars().enumerate() {
        let gx = x + k as i64 * (i64::from(GLYPH_W) + 1) * s;
        for (row, bits) in glyph(c).iter().enumerate() {
            for col in 0..GLYPH_W as i64 {
                if bits >> (GLYPH_W as i64 - 1 - col) & 1 == 1 {
                    fill_rect(image, gx + col * s, y + row as i64 * s, s, s, color);
                }
            }
        }
    }
}

/// Fills the rectangle `[x, x+w) x [y, y+h)`, clipped to the image.
pub fn fill_rect(image: &mut ColorImage, x: i64, y: i64, w: i64, h: i64, color: [u8; 3]) {
    let (iw, ih) = (i64::from(image.width), i64::from(image.height));
    for py in y.max(0)..(y + h).min(ih) {
        for px in x.max(0)..(x + w).min(iw) {
            image.data[(py * iw + px) as usize] = color;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blank(w: u32, h: u32) -> ColorImage {
        ColorImage { width: w, height: h, data: vec![[255; 3]; (w * h) as usize] }
    }

    fn ink(image: &ColorImage) -> usize {
        image.data.iter().filter(|p| **p == [0, 0, 0]).count()
    }

    #[test]
    fn glyphs_draw_their_hand_counted_pixels() {
        // '1': 1 + 2 + 1 + 1 + 1 + 1 + 3 = 10 pixels; '-': 5; at scale 2 each pixel is 4.
        let mut img = blank(20, 10);
        draw_text(&mut img, 0, 0, "1", 1, [0, 0, 0]);
        assert_eq!(ink(&img), 10);
        let mut img = blank(40, 20);
        draw_text(&mut img, 1, 1, "-", 2, [0, 0, 0]);
        assert_eq!(ink(&img), 20);
        // The bar of '-' is row 3: at scale 2, rows 1 + 6 and 1 + 7, columns 1..11.
        assert_eq!(img.data[(7 * 40 + 1) as usize], [0, 0, 0]);
        assert_eq!(img.data[(7 * 40 + 11) as usize], [255; 3]);
        assert_eq!(text_width("12.5", 1), 23);
        assert_eq!(text_width("", 3), 0);
    }

    #[test]
    fn clipping_never_panics() {
        // '8' at (-2, -2): only font rows 2..6, columns 2..4 land inside: 1 + 2 + 1 + 1 + 2 pixels.
        let mut img = blank(10, 10);
        draw_text(&mut img, -2, -2, "8", 1, [0, 0, 0]);
        assert_eq!(ink(&img), 7);
        draw_text(&mut img, 9, 9, "8888", 3, [0, 0, 0]);
        draw_text(&mut img, -100, -100, "8", 3, [0, 0, 0]);
        assert_eq!(ink(&img), 7, "fully outside draws nothing");
    }
}
