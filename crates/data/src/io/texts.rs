//! HumanML3D caption files: one caption per line, `caption#word/POS word/POS ...#start#end`.

use std::path::Path;

#[derive(Clone, Debug, PartialEq)]
pub struct Caption {
    pub text: String,
    /// (word, part-of-speech) pairs.
    pub tokens: Vec<(String, String)>,
    /// Seconds; (0, 0) means the whole clip. NaN tags are read as 0 (as MDM does).
    pub start: f64,
    pub end: f64,
}

impl Caption {
    pub fn whole_clip(&self) -> bool {
        self.start == 0.0 && self.end == 0.0
    }

    /// The line as written in a HumanML3D text file.
    pub fn to_line(&self) -> String {
        let toks: Vec<String> = self.tokens.iter().map(|(w, p)| format!("{w}/{p}")).collect();
        format!("{}#{}#{:.1}#{:.1}", self.text, toks.join(" "), self.start, self.end)
    }
}

/// What is wrong with a caption line (the caller adds file and line).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CaptionError {
    #[error("expected 4 '#'-separated fields (caption#tokens#start#end), found {0}")]
    Fields(usize),
    #[error("empty caption")]
    Empty,
    #[error("token '{0}' is not word/POS")]
    Token(String),
    #[error("{what} tag '{tag}' is not a number")]
    Tag { what: &'static str, tag: String },
    #[error("bad time span {start}..{end}")]
    Span { start: f64, end: f64 },
}

/// Parse one caption line; the error says what is wrong (the caller adds file and line).
pub fn parse_line(line: &str) -> Result<Caption, CaptionError> {
    let parts: Vec<&str> = line.split('#').collect();
    if parts.len() != 4 {
        return Err(CaptionError::Fields(parts.len()));
    }
    let text = parts[0].trim();
    if text.is_empty() {
        return Err(CaptionError::Empty);
    }
    let mut tokens = Vec::new();
    for t in parts[1].split_whitespace() {
        let (w, p) = t.rsplit_once('/').ok_or_else(|| CaptionError::Token(t.to_string()))?;
        tokens.push((w.to_string(), p.to_string()));
    }
    let tag = |s: &str, what: &'static str| -> Result<f64, CaptionError> {
        let v: f64 =
            s.trim().parse().map_err(|_| CaptionError::Tag { what, tag: s.to_string() })?;
        Ok(if v.is_nan() { 0.0 } else { v })
    };
    let start = tag(parts[2], "start")?;
    let end = tag(parts[3], "end")?;
    if start < 0.0 || end < 0.0 || (end < start && end != 0.0) {
        return Err(CaptionError::Span { start, end });
    }
    Ok(Caption { text: text.to_string(), tokens, start, end })
}

/// Parse a caption file; errors are `line N: problem` strings, all of them.
pub fn parse_file(path: &Path) -> Result<(Vec<Caption>, Vec<String>), std::io::Error> {
    let text = std::fs::read_to_string(path)?;
    let mut caps = Vec::new();
    let mut errs = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        match parse_line(line) {
            Ok(c) => caps.push(c),
            Err(e) => errs.push(format!("line {}: {e}", i + 1)),
        }
    }
    Ok((caps, errs))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_humanml3d_lines() {
        let c =
            parse_line("a man kicks with something or someone with his left leg.#a/DET man/NOUN kick/VERB with/ADP something/PRON or/CCONJ someone/PRON with/ADP his/DET left/ADJ leg/NOUN#0.0#0.0")
                .unwrap();
        assert!(c.whole_clip());
        assert_eq!(c.tokens[2], ("kick".into(), "VERB".into()));
        let c = parse_line("a person jumps.#a/DET person/NOUN jump/VERB#1.5#4.0").unwrap();
        assert_eq!((c.start, c.end), (1.5, 4.0));
        let c = parse_line("x#x/NOUN#nan#nan").unwrap();
        assert!(c.whole_clip());
        assert!(parse_line("no tags here").unwrap_err().to_string().contains("4 '#'-separated"));
        assert!(parse_line("#a/DET#0.0#0.0").unwrap_err().to_string().contains("empty"));
        assert!(parse_line("a#a/DET#zero#0.0").unwrap_err().to_string().contains("start tag"));
        let c = parse_line("walks.#walk/VERB#0.0#0.0").unwrap();
        assert_eq!(parse_line(&c.to_line()).unwrap(), c);
    }
}
