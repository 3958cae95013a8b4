//! The end of a run in a few console lines: per-shape findings collapsed into one line per
//! kind (the full list stays in `report.json`), and the warning of a run whose photos observed
//! too little of its surfaces.

use super::UvFold;

/// Shapes named in a collapsed line before "...".
const NAMED: usize = 3;

/// `n` thousands-separated (`526,961`).
pub fn thousands(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// A few of `ids` quoted, then "..." when there are more.
pub fn some_ids<'a>(ids: impl IntoIterator<Item = &'a str>) -> String {
    let ids: Vec<&str> = ids.into_iter().collect();
    let mut s: Vec<String> = ids.iter().take(NAMED).map(|id| format!("'{id}'")).collect();
    if ids.len() > NAMED {
        s.push("...".into());
    }
    s.join(", ")
}

/// One console line per kind of the fold's findings: a kind of one shape says it in full
/// ([`UvFold::summary`]); a kind of several counts them and names a few.
pub fn fold_lines(folds: &[UvFold]) -> Vec<String> {
    let mut kinds: Vec<(&str, bool)> = Vec::new();
    for f in folds {
        let k = (f.decision.as_str(), f.atlas_filtered);
        if !kinds.contains(&k) {
            kinds.push(k);
        }
    }
    kinds
        .into_iter()
        .map(|k| {
            let of: Vec<&UvFold> = (folds.iter())
                .filter(|f| (f.decision.as_str(), f.atlas_filtered) == k)
                .collect();
            match of.len() {
                1 => of[0].summary(),
                n => {
                    let (what, why) = fold_kind(k.0, k.1);
                    let ids = some_ids(of.iter().map(|f| f.shape.as_str()));
                    format!("uv fold: {what} for {n} shapes ({why}): {ids}")
                }
            }
        })
        .collect()
}

/// What a fold decision did and why, for a line that counts shapes.
fn fold_kind(decision: &str, filtered: bool) -> (&'static str, &'static str) {
    match (decision, filtered) {
        ("folded", _) => (
            "folded into the input UVs for scene.xml",
            "the repeats agree",
        ),
        ("disagree", true) => (
            "kept on the atlas",
            "the repeats disagree: the albedo does not follow the UVs",
        ),
        ("disagree", false) => (
            "kept on the atlas, unfiltered",
            "the repeats disagree; the sigma filter had left it to the fold",
        ),
        ("coarse", _) => (
            "kept on the atlas",
            "too few repeats for a fold finer than the atlas",
        ),
        _ => ("kept on the atlas", "too few observed texels"),
    }
}

/// The warning of a run whose photos observed under `min_share` of its `covered` texels, or
/// whose textures are mostly fill (`filled`: the texels filled from observed ones, when the
/// run solved for K_d); `None` when neither (or nothing is covered).
pub fn coverage_warning(
    covered: u64,
    observed: u64,
    filled: Option<u64>,
    min_share: f64,
) -> Option<String> {
    if covered == 0 {
        return None;
    }
    let seen = observed as f64 / covered as f64;
    let fill = filled.map(|f| f as f64 / covered as f64);
    if seen >= min_share && fill.is_none_or(|f| f <= 1.0 - min_share) {
        return None;
    }
    let fill_part = match fill {
        Some(f) => format!("; {} of the texture is fill", percent(f)),
        None => String::new(),
    };
    Some(format!(
        "only {} of {} covered texels ({}) were observed by a photo{fill_part} (below \
         run.min_observed_share = {min_share}): the textures mostly show the fill, not the \
         photos",
        thousands(observed),
        thousands(covered),
        percent(seen),
    ))
}

/// A share as a percentage with the digits that tell small ones apart (`0.06%`, `99.9%`).
fn percent(x: f64) -> String {
    let p = 100.0 * x;
    match p {
        p if p < 1.0 => format!("{p:.2}%"),
        p if p > 99.0 && p < 100.0 => format!("{p:.1}%"),
        p => format!("{p:.0}%"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fold(shape: &str, decision: &str) -> UvFold {
        UvFold {
            shape: shape.into(),
            decision: decision.into(),
            atlas_filtered: true,
            ..Default::default()
        }
    }

    #[test]
    fn thousands_are_separated() {
        assert_eq!(thousands(0), "0");
        assert_eq!(thousands(999), "999");
        assert_eq!(thousands(1000), "1,000");
        assert_eq!(thousands(526_961), "526,961");
        assert_eq!(thousands(1_048_576), "1,048,576");
    }

    #[test]
    fn fold_findings_collapse_per_kind() {
        let mut folds: Vec<UvFold> = (0..437)
            .map(|i| fold(&format!("shape_{i}"), "few samples"))
            .collect();
        folds.push(fold("floor", "folded"));
        let lines = fold_lines(&folds);
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert_eq!(
            lines[0],
            "uv fold: kept on the atlas for 437 shapes (too few observed texels): 'shape_0', \
             'shape_1', 'shape_2', ..."
        );
        assert_eq!(lines[1], folds[437].summary(), "one shape: said in full");
    }

    #[test]
    fn the_warning_gives_the_figures() {
        let w = coverage_warning(526_961, 309, Some(526_652), 0.5).unwrap();
        assert!(
            w.starts_with(
                "only 309 of 526,961 covered texels (0.06%) were observed by a photo; \
                 99.9% of the texture is fill"
            ),
            "{w}"
        );
        assert!(w.contains("min_observed_share = 0.5"), "{w}");
        let p = coverage_warning(1000, 200, None, 0.5).unwrap();
        assert!(p.contains("(20%)") && !p.contains("fill;"), "{p}");
    }

    #[test]
    fn a_well_observed_run_has_no_warning() {
        assert_eq!(coverage_warning(1000, 800, Some(200), 0.5), None);
        assert_eq!(coverage_warning(1000, 500, None, 0.5), None);
        assert_eq!(coverage_warning(0, 0, Some(0), 0.5), None);
        assert!(
            coverage_warning(1000, 800, Some(600), 0.5).is_some(),
            "mostly fill"
        );
        assert_eq!(coverage_warning(1000, 10, Some(990), 0.0), None, "off");
    }
}
