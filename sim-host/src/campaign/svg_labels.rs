//! Overlap check of the text labels of an SVG figure (as the `plotters` SVG backend writes
//! them: `<text x y dy text-anchor font-size [transform="rotate(a, cx, cy)"]>label</text>`).
//!
//! A browser lays the text out with its own font, which we do not have; the box of a label is
//! estimated from its font size and character count: width `0.6 * font_size * chars` (the
//! average advance of a sans-serif font is about 0.5-0.55 em, so this errs on the wide side),
//! height `font_size`, placed by `text-anchor` and the vertical offset `dy` the backend uses
//! (`0.76em`: top at `y`; `0.5ex`: centred on `y`; `-0.5ex`: bottom at `y`; none: baseline at
//! `y`), then rotated by the label's `rotate` transform.

/// Width of a character, in font sizes.
pub const CHAR_WIDTH_EM: f64 = 0.6;

/// The estimated box of a label, in SVG user units.
#[derive(Debug, Clone, PartialEq)]
pub struct Label {
    /// The text (entities decoded).
    pub text: String,
    /// Left.
    pub x0: f64,
    /// Top.
    pub y0: f64,
    /// Right.
    pub x1: f64,
    /// Bottom.
    pub y1: f64,
}

impl Label {
    /// Overlap area with `other` is more than `tol` wide and high.
    pub fn overlaps(&self, other: &Label, tol: f64) -> bool {
        let w = self.x1.min(other.x1) - self.x0.max(other.x0);
        let h = self.y1.min(other.y1) - self.y0.max(other.y0);
        w > tol && h > tol
    }
}

fn attr<'a>(tag: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let start = tag.find(&key)? + key.len();
    let end = tag[start..].find('"')? + start;
    Some(&tag[start..end])
}

fn decode(text: &str) -> String {
    text.replace("&lt;", "<")
        .replace("&gt;", ">")
        .replace("&quot;", "\"")
        .replace("&apos;", "'")
        .replace("&#39;", "'")
        .replace("&amp;", "&")
}

/// The labels of `svg` with their estimated boxes.
pub fn labels(svg: &str) -> anyhow::Result<Vec<Label>> {
    let mut out = Vec::new();
    let mut rest = svg;
    while let Some(start) = rest.find("<text") {
        let after = &rest[start..];
        let open_end = after
            .find('>')
            .ok_or_else(|| anyhow::anyhow!("unterminated <text> tag"))?;
        let tag = &after[..open_end];
        let body_and_rest = &after[open_end + 1..];
        let close = body_and_rest
            .find("</text>")
            .ok_or_else(|| anyhow::anyhow!("<text> without </text>"))?;
        let text = decode(body_and_rest[..close].trim());
        rest = &body_and_rest[close + "</text>".len()..];
        let num = |name: &str| -> anyhow::Result<f64> {
            attr(tag, name)
                .ok_or_else(|| anyhow::anyhow!("<text> without {name}: {tag}"))?
                .trim_end_matches("px")
                .parse::<f64>()
                .map_err(|e| anyhow::anyhow!("<text> {name}: {e}"))
        };
        let (x, y, fs) = (num("x")?, num("y")?, num("font-size")?);
        let w = CHAR_WIDTH_EM * fs * text.chars().count() as f64;
        let h = fs;
        let (x0, x1) = match attr(tag, "text-anchor").unwrap_or("start") {
            "middle" => (x - 0.5 * w, x + 0.5 * w),
            "end" => (x - w, x),
            _ => (x, x + w),
        };
        let (y0, y1) = match attr(tag, "dy") {
            Some("0.76em") => (y, y + h),
            Some("0.5ex") => (y - 0.5 * h, y + 0.5 * h),
            Some("-0.5ex") => (y - h, y),
            _ => (y - 0.8 * h, y + 0.2 * h),
        };
        let mut corners = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)];
        if let Some(t) = attr(tag, "transform") {
            let args = t
                .strip_prefix("rotate(")
                .and_then(|a| a.strip_suffix(')'))
                .ok_or_else(|| anyhow::anyhow!("unsupported transform {t:?}"))?;
            let v: Vec<f64> = args
                .split([',', ' '])
                .filter(|s| !s.is_empty())
                .map(str::parse)
                .collect::<Result<_, _>>()?;
            let (a, cx, cy) = match v.as_slice() {
                [a] => (*a, 0.0, 0.0),
                [a, cx, cy] => (*a, *cx, *cy),
                _ => anyhow::bail!("unsupported transform {t:?}"),
            };
            let (s, c) = a.to_radians().sin_cos();
            for p in &mut corners {
                let (dx, dy) = (p.0 - cx, p.1 - cy);
                *p = (cx + c * dx - s * dy, cy + s * dx + c * dy);
            }
        }
        let xs = corners.map(|p| p.0);
        let ys = corners.map(|p| p.1);
        out.push(Label {
            text,
            x0: xs.iter().copied().fold(f64::INFINITY, f64::min),
            y0: ys.iter().copied().fold(f64::INFINITY, f64::min),
            x1: xs.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            y1: ys.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        });
    }
    Ok(out)
}

/// Pairs of labels of `svg` whose boxes overlap by more than half a unit both ways.
pub fn overlapping(svg: &str) -> anyhow::Result<Vec<(Label, Label)>> {
    let all = labels(svg)?;
    let mut pairs = Vec::new();
    for (i, a) in all.iter().enumerate() {
        for b in &all[i + 1..] {
            if a.overlaps(b, 0.5) {
                pairs.push((a.clone(), b.clone()));
            }
        }
    }
    Ok(pairs)
}

/// Labels of `svg` that stick out of its `width` x `height` canvas by more than half a unit.
pub fn outside(svg: &str, width: f64, height: f64) -> anyhow::Result<Vec<Label>> {
    Ok(labels(svg)?
        .into_iter()
        .filter(|l| l.x0 < -0.5 || l.y0 < -0.5 || l.x1 > width + 0.5 || l.y1 > height + 0.5)
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn campaign_svg_labels_boxes_and_overlaps() {
        let svg = r##"<svg>
<text x="100" y="50" dy="0.76em" text-anchor="middle" font-size="10" fill="#000">
abcde
</text>
<text x="118" y="55" dy="0.76em" text-anchor="start" font-size="10">x &amp; y</text>
<text x="300" y="50" dy="0.5ex" text-anchor="end" font-size="10" transform="rotate(270, 300, 50)">vertical</text>
</svg>"##;
        let l = labels(svg).unwrap();
        assert_eq!(l.len(), 3);
        // 5 chars at 10: 30 wide, centred on 100; top at 50.
        assert_eq!(
            (l[0].x0, l[0].x1, l[0].y0, l[0].y1),
            (85.0, 115.0, 50.0, 60.0)
        );
        assert_eq!(l[1].text, "x & y");
        // Rotated by 270 deg: 48 tall, 10 wide.
        assert!((l[2].x1 - l[2].x0 - 10.0).abs() < 1e-9);
        assert!((l[2].y1 - l[2].y0 - 48.0).abs() < 1e-9);
        // The first two do not touch (115 < 118); move the second left and they do.
        assert!(overlapping(svg).unwrap().is_empty());
        let moved = svg.replace("x=\"118\"", "x=\"110\"");
        let pairs = overlapping(&moved).unwrap();
        assert_eq!(pairs.len(), 1);
        assert_eq!(pairs[0].0.text, "abcde");
        assert!(outside(svg, 400.0, 400.0).unwrap().is_empty());
        assert_eq!(outside(svg, 200.0, 400.0).unwrap().len(), 1);
    }
}
