//! BERT's tokenizer as a `tokenizer.json` of Hugging Face's format describes it for BERT models
//! (all-MiniLM-L6-v2 among them): special tokens split off the raw text, then `BertNormalizer`
//! (control characters dropped, whitespace made spaces, CJK ideographs spaced, accents
//! stripped, lower case), `BertPreTokenizer` (words split at whitespace, every punctuation mark
//! a word of its own), greedy longest-match `WordPiece`, and the post-processor's
//! `[CLS] … [SEP]`, truncated to the file's length. Other pipelines in the file are refused
//! when it loads. Written for this one family, so the build does without a general tokenizer
//! library and its regex engine; tests/text_encoder.rs holds it to Hugging Face's output.

use std::collections::HashMap;
use std::path::Path;

use serde::Deserialize;
use unicode_categories::UnicodeCategories;
use unicode_normalization::UnicodeNormalization;

use super::TextError;

/// The parts of `tokenizer.json` this tokenizer reads; any other pipeline fails to parse.
#[derive(Deserialize)]
struct File {
    truncation: Option<Truncation>,
    padding: Option<Padding>,
    #[serde(default)]
    added_tokens: Vec<AddedToken>,
    normalizer: Normalizer,
    pre_tokenizer: PreTokenizer,
    post_processor: PostProcessor,
    model: Model,
}

#[derive(Deserialize)]
struct Truncation {
    max_length: usize,
    #[serde(default = "right")]
    direction: String,
}

fn right() -> String {
    "Right".into()
}

#[derive(Deserialize)]
struct Padding {
    pad_id: u32,
}

#[derive(Deserialize)]
struct AddedToken {
    id: u32,
    content: String,
    #[serde(default)]
    single_word: bool,
    #[serde(default)]
    lstrip: bool,
    #[serde(default)]
    rstrip: bool,
    #[serde(default)]
    normalized: bool,
}

#[derive(Deserialize)]
#[serde(tag = "type")]
enum Normalizer {
    BertNormalizer {
        clean_text: bool,
        handle_chinese_chars: bool,
        strip_accents: Option<bool>,
        lowercase: bool,
    },
}

#[derive(Deserialize)]
#[serde(tag = "type")]
enum PreTokenizer {
    BertPreTokenizer,
}

#[derive(Deserialize)]
#[serde(tag = "type")]
enum PostProcessor {
    TemplateProcessing { single: Vec<Piece>, special_tokens: HashMap<String, Special> },
    BertProcessing { cls: (String, u32), sep: (String, u32) },
}

#[derive(Deserialize)]
enum Piece {
    SpecialToken { id: String },
    Sequence(serde::de::IgnoredAny),
}

#[derive(Deserialize)]
struct Special {
    ids: Vec<u32>,
}

#[derive(Deserialize)]
#[serde(tag = "type")]
enum Model {
    WordPiece {
        unk_token: String,
        continuing_subword_prefix: String,
        max_input_chars_per_word: usize,
        vocab: HashMap<String, u32>,
    },
}

/// A loaded tokenizer; [`WordPiece::encode`] gives a text's ids as the encoder reads them.
pub struct WordPiece {
    vocab: HashMap<String, u32>,
    unk: u32,
    prefix: String,
    max_word_chars: usize,
    clean_text: bool,
    chinese_chars: bool,
    strip_accents: bool,
    lowercase: bool,
    /// Ids before and after the text (`[CLS]`, `[SEP]`).
    head: Vec<u32>,
    tail: Vec<u32>,
    /// Most ids in an encoding, the head and tail included.
    max_len: Option<usize>,
    pad: u32,
    /// Tokens matched in the raw text before normalisation, longest first.
    added: Vec<(String, u32)>,
}

impl WordPiece {
    /// Load `tokenizer.json`; a pipeline other than BERT's is an error naming the file.
    pub fn from_file(path: &Path) -> Result<WordPiece, TextError> {
        let bad = |msg: String| TextError::Bad { path: path.to_path_buf(), msg };
        let bytes = std::fs::read(path).map_err(|e| bad(e.to_string()))?;
        let file: File = serde_json::from_slice(&bytes).map_err(|e| bad(e.to_string()))?;
        WordPiece::from_parts(file).map_err(bad)
    }

    fn from_parts(file: File) -> Result<WordPiece, String> {
        let Normalizer::BertNormalizer {
            clean_text,
            handle_chinese_chars,
            strip_accents,
            lowercase,
        } = file.normalizer;
        let PreTokenizer::BertPreTokenizer = file.pre_tokenizer;
        let Model::WordPiece {
            unk_token,
            continuing_subword_prefix,
            max_input_chars_per_word,
            vocab,
        } = file.model;
        let unk = *vocab
            .get(&unk_token)
            .ok_or(format!("unk_token {unk_token:?} is not in the vocabulary"))?;
        let (head, tail) = template(file.post_processor)?;
        if let Some(t) = &file.truncation {
            if t.direction != "Right" {
                return Err(format!("truncation direction {:?} is not supported", t.direction));
            }
        }
        let mut added = Vec::new();
        for a in file.added_tokens {
            if a.normalized || a.single_word || a.lstrip || a.rstrip {
                return Err(format!(
                    "added token {:?}: only plain raw-text tokens are supported",
                    a.content
                ));
            }
            added.push((a.content, a.id));
        }
        added.sort_by_key(|(s, _)| std::cmp::Reverse(s.len()));
        Ok(WordPiece {
            vocab,
            unk,
            prefix: continuing_subword_prefix,
            max_word_chars: max_input_chars_per_word,
            clean_text,
            chinese_chars: handle_chinese_chars,
            strip_accents: strip_accents.unwrap_or(lowercase),
            lowercase,
            head,
            tail,
            max_len: file.truncation.map(|t| t.max_length),
            pad: file.padding.map_or(0, |p| p.pad_id),
            added,
        })
    }

    /// The id that pads a batch's shorter encodings.
    pub fn pad_id(&self) -> u32 {
        self.pad
    }

    /// A text's ids: the head, its word pieces (truncated to the file's length), the tail.
    pub fn encode(&self, text: &str) -> Vec<u32> {
        let mut body = Vec::new();
        for (part, id) in self.split_added(text) {
            match id {
                Some(id) => body.push(id),
                None => {
                    let normal = self.normalize(part);
                    for word in pre_tokenize(&normal) {
                        self.word_pieces(word, &mut body);
                    }
                }
            }
        }
        if let Some(max) = self.max_len {
            body.truncate(max.saturating_sub(self.head.len() + self.tail.len()));
        }
        [self.head.as_slice(), &body, &self.tail].concat()
    }

    /// The raw text cut at the added tokens (leftmost, longest first): text runs and token ids.
    fn split_added<'a>(&self, text: &'a str) -> Vec<(&'a str, Option<u32>)> {
        let mut parts = Vec::new();
        let (mut start, mut at) = (0, 0);
        while at < text.len() {
            let hit = self.added.iter().find(|(s, _)| text[at..].starts_with(s.as_str()));
            match hit {
                Some((s, id)) => {
                    if start < at {
                        parts.push((&text[start..at], None));
                    }
                    parts.push((&text[at..at + s.len()], Some(*id)));
                    at += s.len();
                    start = at;
                }
                None => at += text[at..].chars().next().map_or(1, char::len_utf8),
            }
        }
        if start < text.len() {
            parts.push((&text[start..], None));
        }
        parts
    }

    /// `BertNormalizer`, its steps in its order.
    fn normalize(&self, text: &str) -> String {
        let mut s: String = if self.clean_text {
            text.chars()
                .filter(|&c| c != '\0' && c != '\u{fffd}' && !is_control(c))
                .map(|c| if is_whitespace(c) { ' ' } else { c })
                .collect()
        } else {
            text.to_string()
        };
        if self.chinese_chars && s.chars().any(is_chinese) {
            s = s
                .chars()
                .flat_map(|c| if is_chinese(c) { vec![' ', c, ' '] } else { vec![c] })
                .collect();
        }
        if self.strip_accents {
            s = s.nfd().filter(|c| !c.is_mark_nonspacing()).collect();
        }
        if self.lowercase {
            s = s.chars().flat_map(char::to_lowercase).collect();
        }
        s
    }

    /// Greedy longest-match pieces of one word, or the unknown token where a piece is missing.
    fn word_pieces(&self, word: &str, out: &mut Vec<u32>) {
        if word.chars().count() > self.max_word_chars {
            out.push(self.unk);
            return;
        }
        let first = out.len();
        let mut start = 0;
        while start < word.len() {
            let mut end = word.len();
            let found = loop {
                if end <= start {
                    break None;
                }
                let piece = &word[start..end];
                let id = if start == 0 {
                    self.vocab.get(piece)
                } else {
                    self.vocab.get(&format!("{}{piece}", self.prefix))
                };
                if let Some(&id) = id {
                    break Some(id);
                }
                end -= piece.chars().next_back().map_or(1, char::len_utf8);
            };
            match found {
                Some(id) => out.push(id),
                None => {
                    out.truncate(first);
                    out.push(self.unk);
                    return;
                }
            }
            start = end;
        }
    }
}

/// The post-processor's ids before and after a single text.
fn template(p: PostProcessor) -> Result<(Vec<u32>, Vec<u32>), String> {
    match p {
        PostProcessor::BertProcessing { cls, sep } => Ok((vec![cls.1], vec![sep.1])),
        PostProcessor::TemplateProcessing { single, special_tokens } => {
            let (mut head, mut tail, mut seen) = (Vec::new(), Vec::new(), false);
            for piece in single {
                match piece {
                    Piece::Sequence(_) if seen => {
                        return Err("the single template has two sequences".into())
                    }
                    Piece::Sequence(_) => seen = true,
                    Piece::SpecialToken { id } => {
                        let ids = &special_tokens
                            .get(&id)
                            .ok_or(format!("template token {id:?} is not among special_tokens"))?
                            .ids;
                        if seen { &mut tail } else { &mut head }.extend(ids);
                    }
                }
            }
            Ok((head, tail))
        }
    }
}

/// `BertPreTokenizer`: words split at whitespace, every punctuation mark a word of its own.
fn pre_tokenize(text: &str) -> Vec<&str> {
    let mut words = Vec::new();
    for chunk in text.split(char::is_whitespace).filter(|w| !w.is_empty()) {
        let mut start = 0;
        for (i, c) in chunk.char_indices() {
            if is_punctuation(c) {
                if start < i {
                    words.push(&chunk[start..i]);
                }
                words.push(&chunk[i..i + c.len_utf8()]);
                start = i + c.len_utf8();
            }
        }
        if start < chunk.len() {
            words.push(&chunk[start..]);
        }
    }
    words
}

/// ASCII punctuation and Unicode's punctuation classes, as BERT's pre-tokenizer counts them.
fn is_punctuation(c: char) -> bool {
    c.is_ascii_punctuation() || c.is_punctuation()
}

/// Tab, newline and carriage return count as whitespace, not as control characters.
fn is_whitespace(c: char) -> bool {
    matches!(c, '\t' | '\n' | '\r') || c.is_whitespace()
}

fn is_control(c: char) -> bool {
    !matches!(c, '\t' | '\n' | '\r') && c.is_other()
}

/// The CJK Unified Ideographs blocks and their extensions and compatibility ideographs.
fn is_chinese(c: char) -> bool {
    matches!(
        c as u32,
        0x4E00..=0x9FFF
            | 0x3400..=0x4DBF
            | 0x20000..=0x2A6DF
            | 0x2A700..=0x2B73F
            | 0x2B740..=0x2B81F
            | 0x2B920..=0x2CEAF
            | 0xF900..=0xFAFF
            | 0x2F800..=0x2FA1F
    )
}
