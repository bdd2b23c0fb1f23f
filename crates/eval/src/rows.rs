//! Which rows an evaluation runs: the generated settings of the paper's Table 2 (methods at
//! one keyframe rate) and Table 4 (rates), each (name, rate) once.

/// One generated row of the tables.
#[derive(Clone, Debug, PartialEq)]
pub struct Setting {
    pub name: String,
    pub rate: f64,
    /// MDM-inp: keyframes pasted into x0 every step, no keyframe branch.
    pub inpaint: bool,
    /// Transition guidance strength r (0 = off).
    pub transition: f64,
    /// Two stages (KeyMotion; `diffkfc keyframes suggest`): the keyframes are the MDO frames
    /// of a text-only motion of the same caption, which is also what ADE and K-Err compare with.
    pub suggested: bool,
}

/// Which rows an evaluation runs: the main setting, the two-stage row, the Table 2 comparison
/// (DiffKFC with and without transition guidance, MDM-inp), the Table 4 sweep of rates.
#[derive(Clone, Debug, Default)]
pub struct Rows {
    pub rate: f64,
    /// The main setting is the MDM-inp baseline.
    pub inpaint: bool,
    pub transition: f64,
    pub compare: bool,
    pub two_stage: bool,
    pub sweep: Vec<f64>,
}

impl Rows {
    /// The settings, each (name, rate) once, in the order above.
    pub fn settings(&self) -> Vec<Setting> {
        let make = |inpaint: bool, transition: f64, rate: f64| Setting {
            name: Setting::name_of(inpaint, transition),
            rate,
            inpaint,
            transition,
            suggested: false,
        };
        let mut v = vec![make(self.inpaint, self.transition, self.rate)];
        if self.two_stage {
            v.push(Setting {
                name: "DiffKFC, suggested keys".into(),
                suggested: true,
                ..make(false, self.transition, self.rate)
            });
        }
        if self.compare {
            // Table 2's TG row needs guidance: the paper's r where the main setting has none.
            let r = if self.transition > 0.0 { self.transition } else { 100.0 };
            v.extend([
                make(false, r, self.rate),
                make(false, 0.0, self.rate),
                make(true, 0.0, self.rate),
            ]);
        }
        v.extend(self.sweep.iter().map(|&r| make(self.inpaint, self.transition, r)));
        let mut out: Vec<Setting> = Vec::new();
        for s in v {
            if !out.iter().any(|o| o.name == s.name && o.rate == s.rate) {
                out.push(s);
            }
        }
        out
    }
}

impl Setting {
    /// The method's name in the tables.
    pub fn name_of(inpaint: bool, transition: f64) -> String {
        match (inpaint, transition > 0.0) {
            (false, true) => "DiffKFC".into(),
            (false, false) => "DiffKFC w/o TG".into(),
            (true, false) => "MDM-inp".into(),
            (true, true) => "MDM-inp + TG".into(),
        }
    }
}

#[cfg(test)]
mod rows_tests {
    use super::*;

    /// Table 2 and 4 rows: main first, each (name, rate) once, the TG row guided even when the
    /// main setting is not.
    #[test]
    fn rows_of_the_tables() {
        let rows = Rows {
            rate: 0.05,
            transition: 0.0,
            compare: true,
            two_stage: true,
            sweep: vec![0.0, 0.05, 0.1],
            ..Default::default()
        };
        let names: Vec<(String, f64)> =
            rows.settings().into_iter().map(|s| (s.name, s.rate)).collect();
        let want = [
            ("DiffKFC w/o TG", 0.05),
            ("DiffKFC, suggested keys", 0.05),
            ("DiffKFC", 0.05),
            ("MDM-inp", 0.05),
            ("DiffKFC w/o TG", 0.0),
            ("DiffKFC w/o TG", 0.1),
        ];
        assert_eq!(names, want.map(|(n, r)| (n.to_string(), r)).to_vec());
        assert_eq!(rows.settings()[2].transition, 100.0);
    }
}
