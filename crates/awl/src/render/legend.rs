//! The colour legend of a scalar render: a vertical colormap bar with tick labels in millimetres.

use super::colormap::Colormap;
use super::font::{GLYPH_H, draw_text, fill_rect, text_width};
use crate::image::ColorImage;

/// Where the legend's bar landed, pixels (for callers and tests).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LegendLayout {
    /// Left column of the bar.
    pub bar_x: u32,
    /// Bar width.
    pub bar_w: u32,
    /// Top row of the bar (the colour of the range's high end).
    pub bar_top: u32,
    /// Bottom row of the bar, inclusive (the colour of the low end).
    pub bar_bottom: u32,
}

/// Font scale used for an image of `height` pixels.
fn font_scale(height: u32) -> u32 {
    if height >= 360 { 2 } else { 1 }
}

/// Width of the legend panel the renderer reserves on the right of an image of `height` pixels.
pub fn legend_width(height: u32) -> u32 {
    let s = font_scale(height);
    8 + (8 * s + 6) + 4 + text_width("-000.00", s) + 6
}

/// Round tick values covering `lo..=hi` (steps of 1, 2 or 5 times a power of ten, about `target`
/// of them) and the number of decimals that prints them exactly.
pub fn nice_ticks(lo: f64, hi: f64, target: usize) -> (Vec<f64>, usize) {
    let span = hi - lo;
    if !(span > 0.0 && span.is_finite()) {
        return (if lo.is_finite() { vec![lo] } else { Vec::new() }, 2);
    }
    let raw = span / target.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(10.0 * mag);
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    ((first..=last).map(|k| k as f64 * step).collect(), decimals)
}

/// Draws the legend into the panel starting at column `panel_x` (to the image's right edge): title
/// `mm`, the bar (`hi_mm` at the top), tick marks and labels. `margin` is the free border, pixels.
pub fn draw_legend(
    image: &mut ColorImage,
    panel_x: u32,
    margin: u32,
    colormap: Colormap,
    lo_mm: f64,
    hi_mm: f64,
) -> LegendLayout {
    let s = font_scale(image.height);
    let ink = [40, 40, 40];
    let bar_x = panel_x + 8;
    let bar_w = 8 * s + 6;
    let bar_top = margin + (GLYPH_H + 3) * s + 6;
    let bar_bottom = image.height.saturating_sub(margin + 4 * s).max(bar_top + 1);
    draw_text(image, i64::from(bar_x), i64::from(margin), "mm", s, ink);
    let rows = f64::from(bar_bottom - bar_top);
    for row in bar_top..=bar_bottom {
        let t = f64::from(bar_bottom - row) / rows;
        let color = colormap.rgb(t as f32);
        fill_rect(image, i64::from(bar_x), i64::from(row), i64::from(bar_w), 1, color);
    }
    let (ticks, decimals) = nice_ticks(lo_mm, hi_mm, 5);
    let span = hi_mm - lo_mm;
    for v in ticks {
        let t = if span > 0.0 { (v - lo_mm) / span } else { 0.0 };
        let y = (f64::from(bar_bottom) - t * rows).round() as i64;
        let tick_x = i64::from(bar_x + bar_w);
        fill_rect(image, tick_x, y, i64::from(3 * s), i64::from(s), ink);
        let label = format!("{v:.decimals$}");
        let label = if label.starts_with("-0") && label.trim_start_matches(['-', '0', '.']).is_empty() {
            label[1..].to_string()
        } else {
            label
        };
        let ty = y - i64::from(GLYPH_H * s / 2);
        draw_text(image, tick_x + i64::from(4 * s), ty, &label, s, ink);
    }
    LegendLayout { bar_x, bar_w, bar_top, bar_bottom }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_ticks_are_round_and_inside() {
        let (t, d) = nice_ticks(0.0, 2.3, 5);
        assert_eq!(d, 1);
        assert_eq!(t.len(), 5, "{t:?}");
        assert!((t[4] - 2.0).abs() < 1e-12, "0, 0.5, ..., 2.0: {t:?}");
        let (t, d) = nice_ticks(-10.0, 10.0, 5);
        assert_eq!((t.len(), d), (5, 0), "{t:?}");
        let (t, _) = nice_ticks(1.0, 1.0, 5);
        assert_eq!(t, vec![1.0]);
    }

    #[test]
    fn bar_rows_carry_the_colormap_top_high() {
        let mut img = ColorImage { width: 300, height: 400, data: vec![[255; 3]; 120_000] };
        let l = draw_legend(&mut img, 300 - legend_width(400), 10, Colormap::Viridis, 0.0, 4.0);
        assert!(l.bar_x + l.bar_w + 40 < 300, "labels fit: {l:?}");
        let px = |x: u32, y: u32| img.data[(y * 300 + x) as usize];
        assert_eq!(px(l.bar_x + 2, l.bar_top), Colormap::Viridis.rgb(1.0));
        assert_eq!(px(l.bar_x + 2, l.bar_bottom), Colormap::Viridis.rgb(0.0));
        let mid = (l.bar_top + l.bar_bottom) / 2;
        let expect = Colormap::Viridis.rgb(0.5);
        assert!(px(l.bar_x, mid).iter().zip(expect).all(|(a, b)| a.abs_diff(b) <= 3));
        // Labels: dark ink right of the bar.
        let ink = (l.bar_x + l.bar_w..300).flat_map(|x| (0..400).map(move |y| (x, y)));
        assert!(ink.filter(|&(x, y)| px(x, y) == [40, 40, 40]).count() > 100);
    }
}
