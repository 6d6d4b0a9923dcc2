//! Minimal SVG charts (horizontal bars), so benchmarks can write plots without a plotting stack.

use std::fmt::Write as _;

/// A horizontal bar chart: one bar per (label, value), with a value axis label.
pub fn bars(title: &str, unit: &str, items: &[(String, f64)], log_scale: bool) -> String {
    let width = 760.0;
    let bar_height = 26.0;
    let left = 250.0;
    let top = 50.0;
    let height = top + items.len() as f64 * (bar_height + 10.0) + 40.0;
    let max = items.iter().map(|(_, v)| *v).fold(0.0, f64::max).max(1e-12);
    let scale = |v: f64| -> f64 {
        let plot = width - left - 90.0;
        if log_scale {
            let lo = items
                .iter()
                .map(|(_, v)| *v)
                .filter(|v| *v > 0.0)
                .fold(f64::INFINITY, f64::min)
                .min(max)
                / 2.0;
            plot * ((v.max(lo) / lo).ln() / (max / lo).ln()).clamp(0.0, 1.0)
        } else {
            plot * v / max
        }
    };
    let mut svg = String::new();
    let _ = writeln!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="Helvetica, Arial, sans-serif" font-size="13">"#
    );
    let _ = writeln!(svg, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(
        svg,
        r#"<text x="{}" y="28" font-size="16" font-weight="bold">{}</text>"#,
        10,
        escape(title)
    );
    for (index, (label, value)) in items.iter().enumerate() {
        let y = top + index as f64 * (bar_height + 10.0);
        let w = scale(*value);
        let _ = writeln!(
            svg,
            r#"<text x="{}" y="{}" text-anchor="end">{}</text>"#,
            left - 8.0,
            y + bar_height * 0.68,
            escape(label)
        );
        let _ = writeln!(
            svg,
            r##"<rect x="{left}" y="{y}" width="{w:.1}" height="{bar_height}" fill="#3b6ea8"/>"##
        );
        let _ = writeln!(
            svg,
            r#"<text x="{:.1}" y="{}">{} {}</text>"#,
            left + w + 6.0,
            y + bar_height * 0.68,
            format_value(*value),
            escape(unit)
        );
    }
    let _ = writeln!(
        svg,
        r##"<text x="{left}" y="{}" fill="#555">{}{}</text>"##,
        height - 12.0,
        escape(unit),
        if log_scale { " (log scale)" } else { "" }
    );
    svg.push_str("</svg>\n");
    svg
}

fn format_value(v: f64) -> String {
    if v >= 1e6 {
        format!("{:.2}M", v / 1e6)
    } else if v >= 1e3 {
        format!("{:.1}k", v / 1e3)
    } else if v >= 10.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
    }
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}
