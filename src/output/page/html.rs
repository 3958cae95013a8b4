//! The few HTML pieces the report page is built from: escaped text, tables, numbers in
//! plain words. Hand-written rather than a template crate: the page is a handful of tables
//! and figures, and its text must come out the same for the same run.

use std::fmt::Write as _;

/// `s` safe as HTML text and attribute values.
pub fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            _ => o.push(c),
        }
    }
    o
}

/// A table: a header row and body rows of already-escaped cells; numeric-looking cells are
/// right-aligned by the page's style (`td.n`).
pub fn table(head: &[&str], rows: &[Vec<String>]) -> String {
    let mut t = String::from("<table><thead><tr>");
    for h in head {
        let _ = write!(t, "<th>{}</th>", esc(h));
    }
    t.push_str("</tr></thead><tbody>");
    for r in rows {
        t.push_str("<tr>");
        for c in r {
            let class = if is_number(c) { " class=\"n\"" } else { "" };
            let _ = write!(t, "<td{class}>{c}</td>");
        }
        t.push_str("</tr>");
    }
    t.push_str("</tbody></table>");
    t
}

/// Whether a cell reads as a number (digits, a sign, a decimal point, a unit after a space).
fn is_number(c: &str) -> bool {
    let head = c.split(' ').next().unwrap_or("");
    !head.is_empty()
        && head
            .trim_end_matches('%')
            .chars()
            .all(|ch| ch.is_ascii_digit() || ".-+e,".contains(ch))
        && head.chars().any(|ch| ch.is_ascii_digit())
}

/// A section with an id (the table of contents links to it) and a title.
pub fn section(id: &str, title: &str, body: &str) -> String {
    format!(
        "<section id=\"{}\"><h2>{}</h2>\n{body}</section>\n",
        esc(id),
        esc(title)
    )
}

/// A fraction as a percentage with `d` decimals.
pub fn pct(f: f64, d: usize) -> String {
    format!("{:.*}%", d, 100.0 * f)
}

/// A value with about four significant digits, plain or in exponent form.
pub fn num(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.3e}")
    } else {
        let d = (3 - a.log10().floor() as i32).clamp(0, 4) as usize;
        let t = format!("{v:.d$}");
        match t.contains('.') {
            true => t.trim_end_matches('0').trim_end_matches('.').to_string(),
            false => t,
        }
    }
}

/// An RGB triple as `[r, g, b]` with [`num`] values.
pub fn rgb(v: [f64; 3]) -> String {
    format!("[{}, {}, {}]", num(v[0]), num(v[1]), num(v[2]))
}

/// Seconds as `12.3 s` or `2 min 5 s`.
pub fn secs(s: f64) -> String {
    if s < 120.0 {
        format!("{s:.1} s")
    } else {
        format!("{} min {:.0} s", (s / 60.0).floor(), s % 60.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_escaped_and_numbers_align_right() {
        assert_eq!(
            esc("<a href=\"x\">&'"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;"
        );
        let t = table(
            &["shape", "texels"],
            &[vec!["floor".into(), "1,024".into()]],
        );
        assert!(
            t.contains("<td>floor</td><td class=\"n\">1,024</td>"),
            "{t}"
        );
        assert!(is_number("12.5%") && is_number("3.0 s") && !is_number("cam_0"));
        assert!(!is_number("-") && !is_number("e"));
    }

    #[test]
    fn numbers_read_plainly() {
        assert_eq!(num(0.0), "0");
        assert_eq!(num(0.7251), "0.7251");
        assert_eq!(num(12.345), "12.35");
        assert_eq!(num(123456.0), "1.235e5");
        assert_eq!(num(1.0), "1");
        assert_eq!(num(2.5), "2.5");
        assert_eq!(num(1200.0), "1200");
        assert_eq!(pct(0.01649, 2), "1.65%");
        assert_eq!(secs(33.69), "33.7 s");
        assert_eq!(secs(125.0), "2 min 5 s");
    }
}
