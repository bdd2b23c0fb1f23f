//! A loss-curve SVG from metrics.jsonl: training loss (light), its moving average (dark) and
//! validation loss (points), log-scaled y.

pub fn loss_svg(metrics: &str) -> String {
    let (mut train, mut val) = (Vec::new(), Vec::new());
    for line in metrics.lines() {
        let Ok(v) = serde_json::from_str::<serde_json::Value>(line) else {
            continue;
        };
        let Some(step) = v["step"].as_f64() else {
            continue;
        };
        if let Some(l) = v["loss"].as_f64() {
            train.push((step, l));
        }
        if let Some(l) = v["val_loss"].as_f64() {
            val.push((step, l));
        }
    }
    let (w, h, m) = (640.0, 360.0, 50.0);
    let all: Vec<f64> = train.iter().chain(&val).map(|p| p.1.max(1e-6)).collect();
    if all.is_empty() {
        return format!("<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}'><text x='20' y='30'>no steps yet</text></svg>");
    }
    let (lo, hi) = all.iter().fold((f64::MAX, f64::MIN), |a, &v| (a.0.min(v.ln()), a.1.max(v.ln())));
    let hi = if hi - lo < 1e-9 { lo + 1.0 } else { hi };
    let smax = train.iter().chain(&val).map(|p| p.0).fold(1.0, f64::max);
    let x = |s: f64| m + (w - 2.0 * m) * s / smax;
    let y = |l: f64| h - m - (h - 2.0 * m) * (l.max(1e-6).ln() - lo) / (hi - lo);
    let path = |pts: &[(f64, f64)]| pts.iter().enumerate().map(|(i, p)| format!("{}{:.1},{:.1}", if i == 0 { "M" } else { "L" }, x(p.0), y(p.1))).collect::<String>();
    let k = (train.len() / 50).max(1);
    let smooth: Vec<(f64, f64)> = (0..train.len())
        .map(|i| {
            let a = i.saturating_sub(k);
            let s: f64 = train[a..=i].iter().map(|p| p.1).sum::<f64>() / (i - a + 1) as f64;
            (train[i].0, s)
        })
        .collect();
    let mut s = format!("<svg xmlns='http://www.w3.org/2000/svg' width='{w}' height='{h}' font-family='sans-serif' font-size='12'>");
    s += &format!(
        "<rect width='{w}' height='{h}' fill='white'/><line x1='{m}' y1='{}' x2='{}' y2='{}' stroke='black'/><line x1='{m}' y1='{m}' x2='{m}' y2='{}' stroke='black'/>",
        h - m,
        w - m,
        h - m,
        h - m
    );
    s += &format!("<text x='{}' y='{}' text-anchor='middle'>step</text><text x='12' y='{}' transform='rotate(-90 12 {})' text-anchor='middle'>loss (log)</text>", w / 2.0, h - 12.0, h / 2.0, h / 2.0);
    s += &format!(
        "<text x='{m}' y='{}'>{:.3}</text><text x='{m}' y='{}'>{:.3}</text><text x='{}' y='{}' text-anchor='end'>{smax}</text>",
        m - 6.0,
        hi.exp(),
        h - m + 14.0,
        lo.exp(),
        w - m,
        h - m + 14.0
    );
    s += &format!("<path d='{}' fill='none' stroke='#9bb' stroke-width='1'/><path d='{}' fill='none' stroke='#157' stroke-width='2'/>", path(&train), path(&smooth));
    for p in &val {
        s += &format!("<circle cx='{:.1}' cy='{:.1}' r='3.5' fill='#d60'/>", x(p.0), y(p.1));
    }
    s += &format!("<text x='{}' y='20' text-anchor='end' fill='#157'>train (moving average)</text><text x='{}' y='36' text-anchor='end' fill='#d60'>validation</text></svg>", w - m, w - m);
    s
}
