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

/// A run's texel counts, for [`coverage_warning`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Coverage {
    /// Texels on the surfaces of reconstructed shapes.
    pub covered: u64,
    /// Those a photo observed.
    pub observed: u64,
    /// Those a photo could see at all (in its frame, facing it, unoccluded).
    pub visible: u64,
    /// Those filled from observed ones, when the run solved for K_d.
    pub filled: Option<u64>,
}

/// The warning of a run whose photos observed under `min_share` of its covered texels, or
/// whose textures are mostly fill, with what kept the texels from being observed: no photo
/// could see them (more viewpoints would), or the photos could but their pixels were not
/// read (parts a pixel or two wide: finer photos would, or `fine_geometry` when it is off).
/// Each cause is named when it holds at least a fifth of the texels it concerns. `None` when
/// neither (or nothing is covered).
pub fn coverage_warning(c: &Coverage, min_share: f64, fine_geometry: bool) -> Option<String> {
    if c.covered == 0 {
        return None;
    }
    let seen = c.observed as f64 / c.covered as f64;
    let fill = c.filled.map(|f| f as f64 / c.covered as f64);
    if seen >= min_share && fill.is_none_or(|f| f <= 1.0 - min_share) {
        return None;
    }
    let fill_part = match fill {
        Some(f) => format!("; {} of the texture is fill", percent(f)),
        None => String::new(),
    };
    let mut w = format!(
        "only {} of {} covered texels ({}) were observed by a photo{fill_part} (below \
         run.min_observed_share = {min_share}): the textures mostly show the fill, not the \
         photos",
        thousands(c.observed),
        thousands(c.covered),
        percent(seen),
    );
    let unseen = c.covered.saturating_sub(c.visible);
    if 5 * unseen >= c.covered {
        w += &format!(
            ". No photo could see {} of them ({}): photos from more viewpoints would",
            thousands(unseen),
            percent(unseen as f64 / c.covered as f64)
        );
    }
    let unread = c.visible.saturating_sub(c.observed);
    if unread > 0 && 5 * unread >= c.visible {
        w += &format!(
            ". Of the {} a photo could see, {} were not observed: their pixels straddle an \
             edge or another shape (parts a pixel or two wide in these photos); photos of \
             higher resolution or from nearer observe them",
            thousands(c.visible),
            percent(unread as f64 / c.visible as f64)
        );
        if !fine_geometry {
            w += ", or [projection] fine_geometry = true reads them from pixels that see one \
                  surface";
        }
    }
    Some(w)
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

    fn cov(covered: u64, observed: u64, visible: u64, filled: Option<u64>) -> Coverage {
        Coverage {
            covered,
            observed,
            visible,
            filled,
        }
    }

    #[test]
    fn the_warning_gives_the_figures() {
        let w = coverage_warning(&cov(526_961, 309, 309, Some(526_652)), 0.5, false).unwrap();
        assert!(
            w.starts_with(
                "only 309 of 526,961 covered texels (0.06%) were observed by a photo; \
                 99.9% of the texture is fill"
            ),
            "{w}"
        );
        assert!(w.contains("min_observed_share = 0.5"), "{w}");
        let p = coverage_warning(&cov(1000, 200, 1000, None), 0.5, true).unwrap();
        assert!(p.contains("(20%)") && !p.contains("fill;"), "{p}");
    }

    /// The lego's figures: most texels no photo sees, and most of those it sees not read.
    #[test]
    fn the_warning_names_what_kept_texels_unobserved() {
        let lego = cov(530_119, 31_117, 112_081, Some(499_002));
        let w = coverage_warning(&lego, 0.5, false).unwrap();
        assert!(
            w.contains(
                "No photo could see 418,038 of them (79%): photos from more viewpoints would"
            ),
            "{w}"
        );
        assert!(
            w.contains("Of the 112,081 a photo could see, 72% were not observed"),
            "{w}"
        );
        assert!(w.ends_with("pixels that see one surface"), "{w}");
        let on = coverage_warning(&lego, 0.5, true).unwrap();
        assert!(
            on.ends_with("from nearer observe them"),
            "fine_geometry on: {on}"
        );
        // all visible texels observed, most not visible: only the viewpoints
        let hidden = coverage_warning(&cov(1000, 100, 100, None), 0.5, false).unwrap();
        assert!(hidden.contains("No photo could see 900") && !hidden.contains("Of the"));
        // every texel visible, few read: only the pixels
        let fine = coverage_warning(&cov(1000, 100, 1000, None), 0.5, false).unwrap();
        assert!(
            !fine.contains("No photo") && fine.contains("Of the 1,000"),
            "{fine}"
        );
        // a cause under a fifth is not named
        let few = coverage_warning(&cov(1000, 300, 850, None), 0.5, false).unwrap();
        assert!(
            !few.contains("No photo") && few.contains("Of the 850"),
            "{few}"
        );
    }

    #[test]
    fn a_well_observed_run_has_no_warning() {
        let w = |c: Coverage| coverage_warning(&c, 0.5, false);
        assert_eq!(w(cov(1000, 800, 1000, Some(200))), None);
        assert_eq!(w(cov(1000, 500, 1000, None)), None);
        assert_eq!(w(cov(0, 0, 0, Some(0))), None);
        assert!(w(cov(1000, 800, 1000, Some(600))).is_some(), "mostly fill");
        let off = coverage_warning(&cov(1000, 10, 1000, Some(990)), 0.0, false);
        assert_eq!(off, None, "off");
    }
}
