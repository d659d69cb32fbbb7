//! Small SVG charts for reports (bar, line and histogram), written as text: no fonts, no
//! dependencies; the browser lays out the labels.

use std::fmt::Write;

use super::legend::nice_ticks;
use crate::error::{Error, Result};

/// Frame and labels of a chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    /// Title above the plot.
    pub title: String,
    /// Label of the x axis.
    pub x_label: String,
    /// Label of the y axis.
    pub y_label: String,
    /// Width, pixels (SVG user units).
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
}

impl Chart {
    /// A 560 x 260 chart.
    pub fn new(title: &str, x_label: &str, y_label: &str) -> Self {
        Self { title: title.into(), x_label: x_label.into(), y_label: y_label.into(), width: 560, height: 260 }
    }
}

/// One bar of a bar chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Bar {
    /// Category label under the bar.
    pub label: String,
    /// Height (non-finite bars are left out).
    pub value: f64,
    /// CSS color.
    pub color: String,
}

/// One line of a line chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Name in the key.
    pub name: String,
    /// CSS color.
    pub color: String,
    /// `(x, y)` points, drawn in order (non-finite points are left out).
    pub points: Vec<(f64, f64)>,
}

/// Escapes `&`, `<`, `>`, `"` and `'` for XML/HTML text and attribute values.
pub fn xml_escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            _ => out.push(c),
        }
    }
    out
}

const LEFT: f64 = 60.0;
const RIGHT: f64 = 16.0;
const TOP: f64 = 30.0;
const BOTTOM: f64 = 44.0;

/// Axes mapping data to SVG coordinates.
struct Axes {
    x: (f64, f64),
    y: (f64, f64),
    w: f64,
    h: f64,
}

impl Axes {
    fn new(chart: &Chart, x: (f64, f64), y: (f64, f64)) -> Self {
        let pad = |(a, b): (f64, f64)| if b > a { (a, b) } else { (a - 0.5, a + 0.5) };
        Self { x: pad(x), y: pad(y), w: f64::from(chart.width), h: f64::from(chart.height) }
    }
    fn sx(&self, v: f64) -> f64 {
        LEFT + (v - self.x.0) / (self.x.1 - self.x.0) * (self.w - LEFT - RIGHT)
    }
    fn sy(&self, v: f64) -> f64 {
        self.h - BOTTOM - (v - self.y.0) / (self.y.1 - self.y.0) * (self.h - TOP - BOTTOM)
    }
}

/// Draws frame, grid, tick labels and titles; `x_ticks`: label the x axis (`integer_x`: whole
/// numbers only).
fn open(chart: &Chart, axes: &Axes, x_ticks: bool, integer_x: bool) -> String {
    let (w, h) = (chart.width, chart.height);
    let mut s = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" viewBox=\"0 0 {w} {h}\" \
         font-family=\"sans-serif\" font-size=\"11\">\n<rect width=\"{w}\" height=\"{h}\" fill=\"white\"/>\n\
         <text x=\"{}\" y=\"18\" text-anchor=\"middle\" font-size=\"13\" font-weight=\"bold\">{}</text>\n",
        w / 2,
        xml_escape(&chart.title)
    );
    let (x0, x1, y0, y1) = (LEFT, axes.w - RIGHT, TOP, axes.h - BOTTOM);
    let (ticks, dec) = nice_ticks(axes.y.0, axes.y.1, 5);
    for v in ticks {
        let y = axes.sy(v);
        let _ = writeln!(s, "<line x1=\"{x0}\" x2=\"{x1}\" y1=\"{y:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/>");
        let _ = writeln!(s, "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{v:.dec$}</text>", x0 - 4.0, y + 4.0);
    }
    if x_ticks {
        let (ticks, dec) = nice_ticks(axes.x.0, axes.x.1, 6);
        let dec = if integer_x { 0 } else { dec };
        for v in ticks.into_iter().filter(|v| !integer_x || v.fract() == 0.0) {
            let x = axes.sx(v);
            let _ = writeln!(s, "<text x=\"{x:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{v:.dec$}</text>", y1 + 14.0);
        }
    }
    let _ = writeln!(
        s,
        "<rect x=\"{x0}\" y=\"{y0}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"#444\"/>",
        x1 - x0,
        y1 - y0
    );
    let _ = writeln!(
        s,
        "<text x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n<text transform=\"translate(14 {:.1}) rotate(-90)\" \
         text-anchor=\"middle\">{}</text>",
        (x0 + x1) / 2.0,
        chart.height - 6,
        xml_escape(&chart.x_label),
        (y0 + y1) / 2.0,
        xml_escape(&chart.y_label)
    );
    s
}

fn range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.filter(|v| v.is_finite()).fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((a, b)) => Some((a.min(v), b.max(v))),
    })
}

/// A bar chart (y from 0 or the smallest value); bars in order, labels underneath.
pub fn bar_chart(chart: &Chart, bars: &[Bar]) -> String {
    let (lo, hi) = range(bars.iter().map(|b| b.value)).unwrap_or((0.0, 1.0));
    let axes = Axes::new(chart, (0.0, bars.len().max(1) as f64), (lo.min(0.0), hi.max(0.0) * 1.05));
    let mut s = open(chart, &axes, false, false);
    let slot = (axes.sx(1.0) - axes.sx(0.0)).max(1.0);
    for (k, b) in bars.iter().enumerate() {
        let x = axes.sx(k as f64) + slot * 0.15;
        if b.value.is_finite() {
            let (ya, yb) = (axes.sy(b.value.max(0.0)), axes.sy(b.value.min(0.0)));
            let _ = writeln!(
                s,
                "<rect x=\"{x:.1}\" y=\"{ya:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"{}\"><title>{}: {}</title></rect>",
                slot * 0.7,
                (yb - ya).max(0.5),
                xml_escape(&b.color),
                xml_escape(&b.label),
                b.value
            );
        }
        let _ = writeln!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            x + slot * 0.35,
            axes.h - BOTTOM + 14.0,
            xml_escape(&b.label)
        );
    }
    s.push_str("</svg>\n");
    s
}

/// A line chart with a key of the series' names.
pub fn line_chart(chart: &Chart, series: &[Series]) -> String {
    let all = || series.iter().flat_map(|s| s.points.iter()).filter(|(x, y)| x.is_finite() && y.is_finite());
    let xr = range(all().map(|p| p.0)).unwrap_or((0.0, 1.0));
    let (ylo, yhi) = range(all().map(|p| p.1)).unwrap_or((0.0, 1.0));
    let axes = Axes::new(chart, xr, (ylo.min(0.0), yhi * 1.05));
    let mut s = open(chart, &axes, true, all().all(|p| p.0.fract() == 0.0));
    for (k, line) in series.iter().enumerate() {
        let pts: Vec<String> = line
            .points
            .iter()
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .map(|&(x, y)| format!("{:.1},{:.1}", axes.sx(x), axes.sy(y)))
            .collect();
        let color = xml_escape(&line.color);
        let _ = writeln!(
            s,
            "<polyline fill=\"none\" stroke=\"{color}\" stroke-width=\"1.5\" points=\"{}\"/>",
            pts.join(" ")
        );
        for p in &pts {
            let (x, y) = p.split_once(',').unwrap_or(("0", "0"));
            let _ = writeln!(s, "<circle cx=\"{x}\" cy=\"{y}\" r=\"2.5\" fill=\"{color}\"/>");
        }
        let ky = TOP + 12.0 + 13.0 * k as f64;
        let kx = axes.w - RIGHT - 80.0;
        let _ = writeln!(
            s,
            "<rect x=\"{kx:.1}\" y=\"{:.1}\" width=\"10\" height=\"3\" fill=\"{color}\"/><text x=\"{:.1}\" y=\"{ky:.1}\">{}</text>",
            ky - 4.0,
            kx + 14.0,
            xml_escape(&line.name)
        );
    }
    s.push_str("</svg>\n");
    s
}

/// A histogram: `counts[k]` points fell in `[edges[k], edges[k+1])`.
///
/// # Errors
/// [`Error::Invalid`] unless there is one more edge than counts and the edges are finite and
/// increasing.
pub fn histogram(chart: &Chart, edges: &[f64], counts: &[u64], color: &str) -> Result<String> {
    if edges.len() != counts.len() + 1 || counts.is_empty() {
        return Err(Error::invalid("histogram", format!("{} edges for {} bins", edges.len(), counts.len())));
    }
    if !edges.iter().all(|e| e.is_finite()) || edges.windows(2).any(|w| w[1] <= w[0]) {
        return Err(Error::invalid("histogram", "edges must be finite and increasing"));
    }
    let top = counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    let axes = Axes::new(chart, (edges[0], edges[edges.len() - 1]), (0.0, top * 1.05));
    let mut s = open(chart, &axes, true, false);
    for (k, &c) in counts.iter().enumerate() {
        let (xa, xb) = (axes.sx(edges[k]), axes.sx(edges[k + 1]));
        let y = axes.sy(c as f64);
        let _ = writeln!(
            s,
            "<rect x=\"{xa:.1}\" y=\"{y:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"{}\" stroke=\"white\" stroke-width=\"0.5\"/>",
            (xb - xa).max(0.5),
            axes.sy(0.0) - y,
            xml_escape(color)
        );
    }
    s.push_str("</svg>\n");
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn count(s: &str, needle: &str) -> usize {
        s.matches(needle).count()
    }

    #[test]
    fn bars_scale_to_the_largest_value() {
        let chart = Chart::new("correction <mm>", "view", "mm");
        let bars: Vec<Bar> = [1.0, 4.0, f64::NAN]
            .iter()
            .enumerate()
            .map(|(k, &v)| Bar { label: k.to_string(), value: v, color: "red".into() })
            .collect();
        let svg = bar_chart(&chart, &bars);
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("correction &lt;mm&gt;"), "title escaped");
        assert_eq!(count(&svg, "fill=\"red\""), 2, "NaN bar left out");
        // y axis 0..4.2 over 186 px (260 - 30 - 44): the 4.0 bar is 4 / 4.2 * 186 = 177.1 px tall.
        assert!(svg.contains("height=\"177.1\""), "{svg}");
    }

    #[test]
    fn histogram_checks_edges_and_draws_every_bin() {
        let chart = Chart::new("error", "mm", "points");
        let svg = histogram(&chart, &[0.0, 1.0, 2.0, 3.0], &[5, 10, 0], "#36c").expect("valid");
        assert_eq!(count(&svg, "fill=\"#36c\""), 3);
        assert!(histogram(&chart, &[0.0, 1.0], &[1, 2], "#36c").is_err());
        assert!(histogram(&chart, &[0.0, 0.0, 1.0], &[1, 2], "#36c").is_err());
        let lines = line_chart(
            &chart,
            &[Series { name: "a".into(), color: "blue".into(), points: vec![(0.0, 10.0), (1.0, 20.0)] }],
        );
        assert_eq!(count(&lines, "<circle"), 2);
        assert!(lines.contains(">1</text>") && !lines.contains(">0.2</text>"), "whole x ticks for whole x");
        assert_eq!(xml_escape("a&'\""), "a&amp;&#39;&quot;");
    }
}
