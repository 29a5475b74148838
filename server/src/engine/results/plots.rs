//! Box plots per controller, split by station, of each metric and rating (median, 25–75 %
//! box, whiskers to the furthest point within 1.5 IQR, outliers marked), and the learning
//! curve (error against test position per seat, a line per subject and the median) — drawn
//! here as SVG and rasterized to PNG with resvg and a vendored font (DejaVu Sans), so the figures need no
//! browser, no plotting library and no internet.

use std::fmt::Write;

use super::inference::quantile::quantile;
use super::learning::LearningCurve;

/// The values of one box: (controller, station, values).
pub type Group = (String, String, Vec<f64>);

const W: f64 = 960.0;
const H: f64 = 520.0;
const LEFT: f64 = 100.0;
const RIGHT: f64 = 24.0;
const TOP: f64 = 64.0;
const BOTTOM: f64 = 84.0;
/// Station colours (Okabe–Ito, safe for colour-blind readers).
const OFF: &str = "#0072B2";
const ON: &str = "#D55E00";
const FONT: &str = "DejaVu Sans, Verdana, sans-serif";

/// User text (a study's name, a compensator's, a label) as SVG text — or HTML text or a
/// double-quoted attribute value (the ethics board's package): escaped, and with the
/// characters XML 1.0 forbids (control characters, U+FFFE, U+FFFF) made spaces, because one
/// of them makes the whole document unparseable for the PNG renderer.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            c if c.is_control() || c == '\u{fffe}' || c == '\u{ffff}' => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

/// A line of the box, left out when it has no length (a box of one value has whiskers of
/// none): the renderer cannot stroke a zero-length path and logs a warning for each.
fn segment(svg: &mut String, (x1, y1): (f64, f64), (x2, y2): (f64, f64)) {
    let at = |v: f64| format!("{v:.1}");
    if at(x1) == at(x2) && at(y1) == at(y2) {
        return;
    }
    let _ = write!(
        svg,
        r##"<line x1="{x1:.1}" y1="{y1:.1}" x2="{x2:.1}" y2="{y2:.1}"/>"##
    );
}

/// A step of 1, 2 or 5 × 10^k giving about `n` ticks over `span`.
fn nice_step(span: f64, n: f64) -> f64 {
    let raw = (span / n).max(f64::MIN_POSITIVE);
    let mag = 10f64.powf(raw.log10().floor());
    let f = raw / mag;
    mag * if f < 1.5 {
        1.0
    } else if f < 3.5 {
        2.0
    } else if f < 7.5 {
        5.0
    } else {
        10.0
    }
}

fn fmt_tick(v: f64, step: f64) -> String {
    if v.abs() >= 1e5 {
        format!("{v:.2e}")
    } else if step >= 1.0 {
        format!("{v:.0}")
    } else {
        let d = (-step.log10()).ceil().max(0.0) as usize;
        format!("{v:.d$}")
    }
}

/// Box statistics: (q1, median, q3, whisker low, whisker high, outliers).
pub fn box_stats(sorted: &[f64]) -> (f64, f64, f64, f64, f64, Vec<f64>) {
    let (q1, med, q3) = (
        quantile(sorted, 0.25),
        quantile(sorted, 0.5),
        quantile(sorted, 0.75),
    );
    let iqr = q3 - q1;
    let (lo_fence, hi_fence) = (q1 - 1.5 * iqr, q3 + 1.5 * iqr);
    let inside: Vec<f64> = sorted
        .iter()
        .copied()
        .filter(|v| *v >= lo_fence && *v <= hi_fence)
        .collect();
    let outliers = sorted
        .iter()
        .copied()
        .filter(|v| *v < lo_fence || *v > hi_fence)
        .collect();
    let lo = inside.first().copied().unwrap_or(q1);
    let hi = inside.last().copied().unwrap_or(q3);
    (q1, med, q3, lo, hi, outliers)
}

/// A figure's SVG up to its title.
fn open_figure(title: &str) -> String {
    let mut svg = String::new();
    let _ = write!(
        svg,
        r##"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="{FONT}"><rect width="100%" height="100%" fill="#ffffff"/><text x="{}" y="26" font-size="19" text-anchor="middle" fill="#111">{}</text>"##,
        W / 2.0,
        esc(title)
    );
    svg
}

/// A figure with nothing to show says so.
fn empty_figure(mut svg: String) -> String {
    let _ = write!(
        svg,
        r##"<text x="{}" y="{}" font-size="18" text-anchor="middle" fill="#555">No completed tests yet</text></svg>"##,
        W / 2.0,
        H / 2.0
    );
    svg
}

/// The value axis of a figure: fitted to the values (or forced to `y_range`), on a log
/// scale when they span more than a factor of 50.
struct YAxis {
    log: bool,
    y0: f64,
    y1: f64,
}

impl YAxis {
    /// Fits the axis and draws its grid, ticks, axis lines and label.
    fn draw(svg: &mut String, values: &[f64], y_range: Option<(f64, f64)>, y_label: &str) -> Self {
        // Mean-square metrics can span orders of magnitude between an unstable and a
        // compensated controller: then a log axis keeps every box readable.
        let lo = values.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let log = y_range.is_none() && lo > 0.0 && hi / lo > 50.0;
        let (mut y0, mut y1) = match y_range {
            Some(r) => r,
            None if log => (lo.log10().floor(), hi.log10().ceil()),
            None => {
                let pad = ((hi - lo) * 0.05).max(hi.abs() * 0.01).max(1e-9);
                (if lo >= 0.0 { 0.0 } else { lo - pad }, hi + pad)
            }
        };
        if y1 <= y0 {
            y1 = y0 + 1.0;
        }
        let step = if log { 1.0 } else { nice_step(y1 - y0, 6.0) };
        if y_range.is_none() && !log {
            y0 = (y0 / step).floor() * step;
            y1 = (y1 / step).ceil() * step;
        }
        let ph = H - TOP - BOTTOM;
        // Grid and y axis (in axis units: log10 of the value on a log axis).
        let first_tick = if y_range.is_some() { y0.ceil() } else { y0 };
        let mut t = first_tick;
        while t <= y1 + step * 0.01 {
            let yy = TOP + ph * (1.0 - (t - y0) / (y1 - y0));
            let label = if log {
                format!("1e{t:.0}")
            } else {
                fmt_tick(t, step)
            };
            let _ = write!(
                svg,
                r##"<line x1="{LEFT}" y1="{yy:.1}" x2="{}" y2="{yy:.1}" stroke="#e3e3e3"/><text x="{}" y="{:.1}" font-size="13" text-anchor="end" fill="#333">{label}</text>"##,
                W - RIGHT,
                LEFT - 8.0,
                yy + 4.0,
            );
            t += step;
        }
        let y_label = if log {
            format!("{y_label}, log scale")
        } else {
            y_label.to_string()
        };
        let _ = write!(
            svg,
            r##"<line x1="{LEFT}" y1="{TOP}" x2="{LEFT}" y2="{}" stroke="#333"/><line x1="{LEFT}" y1="{}" x2="{}" y2="{}" stroke="#333"/><text transform="translate(24 {}) rotate(-90)" font-size="14" text-anchor="middle" fill="#111">{}</text>"##,
            TOP + ph,
            TOP + ph,
            W - RIGHT,
            TOP + ph,
            TOP + ph / 2.0,
            esc(&y_label)
        );
        Self { log, y0, y1 }
    }

    /// The SVG y coordinate of value `v`.
    fn y(&self, v: f64) -> f64 {
        let a = if self.log { v.log10() } else { v };
        TOP + (H - TOP - BOTTOM) * (1.0 - (a - self.y0) / (self.y1 - self.y0))
    }
}

/// The seats' legend, centred under the title.
fn seat_legend(svg: &mut String) {
    for (i, (label, colour)) in [("off the machine (desk)", OFF), ("on the machine", ON)]
        .iter()
        .enumerate()
    {
        let x = W / 2.0 - 200.0 + 230.0 * i as f64;
        let ly = 50.0;
        let _ = write!(
            svg,
            r##"<rect x="{x:.1}" y="{:.1}" width="14" height="14" fill="{colour}" fill-opacity="0.35" stroke="{colour}"/><text x="{:.1}" y="{:.1}" font-size="13" fill="#111">{label}</text>"##,
            ly - 11.0,
            x + 20.0,
            ly + 1.0
        );
    }
}

/// The SVG of one variable. `controllers` fixes the order along the x axis; `y_range`
/// forces the axis (ratings: the scale), otherwise it is fitted to the data.
pub fn box_plot_svg(
    title: &str,
    y_label: &str,
    controllers: &[String],
    groups: &[Group],
    y_range: Option<(f64, f64)>,
) -> String {
    let mut svg = open_figure(title);
    let values: Vec<f64> = groups
        .iter()
        .flat_map(|g| g.2.iter().copied())
        .filter(|v| v.is_finite())
        .collect();
    if values.is_empty() || controllers.is_empty() {
        return empty_figure(svg);
    }
    let axis = YAxis::draw(&mut svg, &values, y_range, y_label);
    let y = |v: f64| axis.y(v);
    let (pw, ph) = (W - LEFT - RIGHT, H - TOP - BOTTOM);
    let slot = pw / controllers.len() as f64;
    let bw = (slot * 0.28).min(60.0);
    for (i, c) in controllers.iter().enumerate() {
        let cx = LEFT + slot * (i as f64 + 0.5);
        let _ = write!(
            svg,
            r##"<text x="{cx:.1}" y="{:.1}" font-size="14" text-anchor="middle" fill="#111">{}</text>"##,
            TOP + ph + 24.0,
            esc(c)
        );
        for (seat, colour, dx) in [("off", OFF, -0.55), ("on", ON, 0.55)] {
            let Some((_, _, vals)) = groups.iter().find(|g| &g.0 == c && g.1 == seat) else {
                continue;
            };
            let mut v: Vec<f64> = vals.iter().copied().filter(|x| x.is_finite()).collect();
            if v.is_empty() {
                continue;
            }
            v.sort_by(f64::total_cmp);
            let (q1, med, q3, lo, hi, outliers) = box_stats(&v);
            let x = cx + dx * bw;
            let _ = write!(svg, r##"<g stroke="{colour}" stroke-width="2">"##);
            // Whiskers and their caps.
            segment(&mut svg, (x, y(hi)), (x, y(q3)));
            segment(&mut svg, (x, y(q1)), (x, y(lo)));
            segment(&mut svg, (x - bw * 0.25, y(hi)), (x + bw * 0.25, y(hi)));
            segment(&mut svg, (x - bw * 0.25, y(lo)), (x + bw * 0.25, y(lo)));
            let _ = write!(
                svg,
                r##"<rect x="{:.1}" y="{:.1}" width="{bw:.1}" height="{:.1}" fill="{colour}" fill-opacity="0.18"/><line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke-width="3"/></g>"##,
                x - bw / 2.0,
                y(q3),
                (y(q1) - y(q3)).max(1.0),
                x - bw / 2.0,
                y(med),
                x + bw / 2.0,
                y(med),
            );
            for o in outliers {
                let _ = write!(
                    svg,
                    r##"<circle cx="{x:.1}" cy="{:.1}" r="4" fill="none" stroke="{colour}" stroke-width="1.5"/>"##,
                    y(o)
                );
            }
            let _ = write!(
                svg,
                r##"<text x="{x:.1}" y="{:.1}" font-size="11" text-anchor="middle" fill="#555">n={}</text>"##,
                TOP + ph + 42.0,
                v.len()
            );
        }
    }
    seat_legend(&mut svg);
    svg.push_str("</svg>");
    svg
}

/// The learning curve: tracking error against test position, one panel per seat (desk on
/// the left, machine on the right, positions 1 … `positions` in each), a thin line per
/// subject and the median per position as a thick line with dots.
pub fn learning_curve_svg(title: &str, curve: &LearningCurve) -> String {
    let mut svg = open_figure(title);
    let values: Vec<f64> = curve
        .subjects
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.mse_tracking_mm2))
        .filter(|v| v.is_finite())
        .collect();
    if values.is_empty() || curve.positions == 0 {
        return empty_figure(svg);
    }
    let axis = YAxis::draw(&mut svg, &values, None, "MSE of tracking (mm²)");
    let ph = H - TOP - BOTTOM;
    let gap = 24.0;
    let panel_w = (W - LEFT - RIGHT - gap) / 2.0;
    let polyline = |svg: &mut String,
                    pts: &[(f64, f64)],
                    colour: &str,
                    width: f64,
                    opacity: f64| {
        if pts.len() < 2 {
            return;
        }
        let coords: Vec<String> = pts.iter().map(|(x, y)| format!("{x:.1},{y:.1}")).collect();
        let _ = write!(
            svg,
            r##"<polyline points="{}" fill="none" stroke="{colour}" stroke-width="{width}" stroke-opacity="{opacity}"/>"##,
            coords.join(" ")
        );
    };
    for (i, (seat, colour, label)) in [
        ("off", OFF, "off the machine (desk)"),
        ("on", ON, "on the machine"),
    ]
    .into_iter()
    .enumerate()
    {
        let x0 = LEFT + i as f64 * (panel_w + gap);
        let x =
            |position: u32| x0 + panel_w * (f64::from(position) - 0.5) / f64::from(curve.positions);
        for p in 1..=curve.positions {
            let _ = write!(
                svg,
                r##"<text x="{:.1}" y="{:.1}" font-size="12" text-anchor="middle" fill="#333">{p}</text>"##,
                x(p),
                TOP + ph + 18.0
            );
        }
        let _ = write!(
            svg,
            r##"<text x="{:.1}" y="{:.1}" font-size="14" text-anchor="middle" fill="{colour}">{label}</text>"##,
            x0 + panel_w / 2.0,
            TOP + ph + 40.0
        );
        for subject in &curve.subjects {
            let pts: Vec<(f64, f64)> = subject
                .points
                .iter()
                .filter(|p| p.seat == seat && p.mse_tracking_mm2.is_finite())
                .map(|p| (x(p.position), axis.y(p.mse_tracking_mm2)))
                .collect();
            polyline(&mut svg, &pts, colour, 1.2, 0.45);
            for (cx, cy) in &pts {
                let _ = write!(
                    svg,
                    r##"<circle cx="{cx:.1}" cy="{cy:.1}" r="2.5" fill="{colour}" fill-opacity="0.45"/>"##
                );
            }
        }
        let med: Vec<(f64, f64)> = curve
            .median
            .iter()
            .filter(|m| m.seat == seat)
            .map(|m| (x(m.position), axis.y(m.mse_tracking_mm2)))
            .collect();
        polyline(&mut svg, &med, "#111", 3.0, 1.0);
        for (cx, cy) in &med {
            let _ = write!(
                svg,
                r##"<circle cx="{cx:.1}" cy="{cy:.1}" r="5" fill="{colour}" stroke="#111" stroke-width="1.5"/>"##
            );
        }
    }
    let slope = match (curve.slope, curve.slope_percent_per_test) {
        (Some(b), Some(percent)) => format!(
            "learning slope {b:.3} {} ({percent:+.1} % per test), median of {} subjects",
            curve.slope_unit, curve.slope_n
        ),
        _ => "no learning slope yet".into(),
    };
    let _ = write!(
        svg,
        r##"<text x="{:.1}" y="{:.1}" font-size="13" text-anchor="middle" fill="#111">test position (both seats) — {}</text>"##,
        LEFT + (W - LEFT - RIGHT) / 2.0,
        H - 14.0,
        esc(&slope)
    );
    seat_legend(&mut svg);
    svg.push_str("</svg>");
    svg
}

static FONT_DATA: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

/// The SVG rendered to PNG (twice the nominal size, for print).
pub fn png(svg: &str) -> anyhow::Result<Vec<u8>> {
    use resvg::{tiny_skia, usvg};
    let mut opt = usvg::Options {
        font_family: "DejaVu Sans".into(),
        ..usvg::Options::default()
    };
    opt.fontdb_mut().load_font_data(FONT_DATA.to_vec());
    let tree = usvg::Tree::from_str(svg, &opt)?;
    let size = tree.size().to_int_size();
    let scale = 2.0;
    let mut pixmap = tiny_skia::Pixmap::new(
        (size.width() as f32 * scale) as u32,
        (size.height() as f32 * scale) as u32,
    )
    .ok_or_else(|| anyhow::anyhow!("empty plot"))?;
    resvg::render(
        &tree,
        tiny_skia::Transform::from_scale(scale, scale),
        &mut pixmap.as_mut(),
    );
    Ok(pixmap.encode_png()?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_statistics_follow_tukey() {
        // 1..=9 plus an outlier at 100 (type-7 quartiles of 10 values): q1 = 3.25, median 5.5,
        // q3 = 7.75, IQR 4.5, upper fence 14.5 → whisker at 9, 100 is an outlier.
        let v: Vec<f64> = (1..=9).map(f64::from).chain([100.0]).collect();
        let (q1, med, q3, lo, hi, out) = box_stats(&v);
        assert_eq!((q1, med, q3), (3.25, 5.5, 7.75));
        assert_eq!((lo, hi), (1.0, 9.0));
        assert_eq!(out, vec![100.0]);
    }

    #[test]
    fn svg_and_png_render_every_box() {
        let groups = vec![
            (
                "pid".to_string(),
                "on".to_string(),
                vec![1.0, 2.0, 3.0, 40.0],
            ),
            ("pid".to_string(), "off".to_string(), vec![1.0, 1.5, 2.0]),
            ("lqr".to_string(), "on".to_string(), vec![0.5, 0.7]),
        ];
        let svg = box_plot_svg(
            "MSE <tracking>",
            "mm²",
            &["pid".into(), "lqr".into()],
            &groups,
            None,
        );
        assert!(svg.contains("MSE &lt;tracking&gt;"));
        assert_eq!(
            svg.matches("<rect x=").count(),
            3 + 2,
            "three boxes and two legend keys"
        );
        assert_eq!(svg.matches("<circle").count(), 1, "one outlier (40)");
        let bytes = png(&svg).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        assert!(bytes.len() > 5_000);
        let empty = box_plot_svg("x", "y", &[], &[], None);
        assert!(empty.contains("No completed tests yet"));
        png(&empty).unwrap();
    }

    #[test]
    fn control_characters_in_user_text_still_render() {
        let name = "study\u{1}\u{7}\u{1b}[31m\u{0}\u{7f}\u{ffff} <b>&\"";
        let groups = vec![("pid\u{2}".to_string(), "on".to_string(), vec![1.0, 2.0])];
        let svg = box_plot_svg(name, "mm\u{8}", &["pid\u{2}".into()], &groups, None);
        assert!(!svg.chars().any(|c| c.is_control()), "{svg}");
        assert!(svg.contains("&lt;b&gt;&amp;&quot;"));
        png(&svg).unwrap();
        png(&box_plot_svg(name, "", &[], &[], None)).unwrap();
    }

    #[test]
    fn the_learning_curve_draws_a_line_per_subject_and_seat_and_the_medians() {
        use super::super::learning::CurvePoint;
        let point = |position, seat: &str, mse| CurvePoint {
            position,
            seat: seat.into(),
            compensator: "pid".into(),
            mse_tracking_mm2: mse,
        };
        // Two subjects, each two tests at each seat; a third with a single test.
        let curve = LearningCurve::from_points(
            4,
            vec![
                (
                    "S01".into(),
                    vec![
                        point(1, "on", 40.0),
                        point(2, "on", 30.0),
                        point(3, "off", 20.0),
                        point(4, "off", 10.0),
                    ],
                ),
                (
                    "S02".into(),
                    vec![
                        point(1, "off", 50.0),
                        point(2, "off", 45.0),
                        point(3, "on", 35.0),
                        point(4, "on", 30.0),
                    ],
                ),
                ("S03".into(), vec![point(1, "on", 60.0)]),
            ],
        );
        let svg = learning_curve_svg("curve <study>", &curve);
        assert!(svg.contains("curve &lt;study&gt;"));
        // Four subject lines (two subjects × two seats; one point draws none) and a median
        // line per seat.
        assert_eq!(svg.matches("<polyline").count(), 4 + 2, "{svg}");
        assert_eq!(svg.matches(r#"r="2.5""#).count(), 9);
        assert_eq!(svg.matches(r#"r="5""#).count(), curve.median.len());
        assert!(svg.contains("ln(mm²) per test position"));
        let bytes = png(&svg).unwrap();
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        let empty = learning_curve_svg("x", &LearningCurve::from_points(10, vec![]));
        assert!(empty.contains("No completed tests yet"));
    }

    /// (x1, y1, x2, y2) of every `<line>` of an SVG.
    fn lines(svg: &str) -> Vec<[f64; 4]> {
        svg.split("<line ")
            .skip(1)
            .map(|l| {
                let attr = |a: &str| -> f64 {
                    let from = l.find(&format!("{a}=\"")).unwrap() + a.len() + 2;
                    let len = l[from..].find('"').unwrap();
                    l[from..from + len].parse().unwrap()
                };
                [attr("x1"), attr("y1"), attr("x2"), attr("y2")]
            })
            .collect()
    }

    #[test]
    fn a_box_of_one_value_has_no_zero_length_line() {
        // n = 1 everywhere (and the same value in every group: a degenerate axis too).
        let groups = vec![
            ("pid".to_string(), "on".to_string(), vec![3.0]),
            ("pid".to_string(), "off".to_string(), vec![3.0]),
        ];
        let svg = box_plot_svg("one each", "mm²", &["pid".into()], &groups, None);
        let all = lines(&svg);
        assert!(all.len() > 4, "{svg}");
        for [x1, y1, x2, y2] in all {
            assert!(x1 != x2 || y1 != y2, "zero-length line in {svg}");
        }
        assert!(svg.contains("n=1"));
        png(&svg).unwrap();
    }
}
