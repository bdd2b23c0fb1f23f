//! Golden tests of the MiniLM text encoder: against sentence-transformers' reference outputs
//! (`../shared/fixtures/minilm/reference_embeddings.json`), and its WordPiece tokenizer against
//! Hugging Face's `tokenizers` on the same `tokenizer.json`: `tests/data/tokenizer_reference.json`
//! holds that library's ids for prompts and for the corners of BERT's normalisation (accents,
//! CJK, control characters, special tokens in the text, unknown words, truncation), written by
//! scripts/tokenizer-reference.py.

use burn::prelude::*;
use diffkfc_data::testing::fixtures;
use diffkfc_model::text::{self, minilm::MiniLm, wordpiece::WordPiece, TextEncoder, TextError};

/// `r`'s value, or None with a notice when the text encoder is absent (a failure under
/// DIFFKFC_REQUIRE_FIXTURES=1).
fn present<T>(r: Result<T, TextError>) -> Option<T> {
    match r {
        Ok(v) => Some(v),
        Err(e) => {
            if std::env::var("DIFFKFC_REQUIRE_FIXTURES").is_ok_and(|v| v == "1") {
                panic!("text encoder required (DIFFKFC_REQUIRE_FIXTURES=1): {e}");
            }
            eprintln!("SKIPPED: {e}");
            None
        }
    }
}

fn encoder() -> Option<MiniLm> {
    present(MiniLm::load(&text::default_dir(), &Device::flex()))
}

fn tokenizer() -> Option<WordPiece> {
    present(WordPiece::from_file(&text::default_dir().join("tokenizer.json")))
}

#[test]
fn matches_reference_embeddings() {
    let Some(path) = fixtures::require("minilm/reference_embeddings.json") else {
        return;
    };
    let Some(enc) = encoder() else { return };
    let reference: serde_json::Value =
        serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    let items = reference["items"].as_array().unwrap();
    assert!(!items.is_empty());
    let texts: Vec<&str> = items.iter().map(|i| i["text"].as_str().unwrap()).collect();
    // Batched, so padding inside a batch is exercised too.
    let embs = enc.embed(&texts).unwrap();
    let mut worst = 1.0f64;
    for (item, e) in items.iter().zip(&embs) {
        let ids: Vec<u32> = item["token_ids"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as u32)
            .collect();
        assert_eq!(enc.token_ids(item["text"].as_str().unwrap()).unwrap(), ids, "{}", item["text"]);
        let r: Vec<f64> =
            item["embedding"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        assert_eq!(r.len(), e.len());
        let dot: f64 = r.iter().zip(e).map(|(a, b)| a * *b as f64).sum();
        let nr: f64 = r.iter().map(|a| a * a).sum::<f64>().sqrt();
        let ne: f64 = e.iter().map(|b| (*b as f64).powi(2)).sum::<f64>().sqrt();
        let cos = dot / nr / ne;
        worst = worst.min(cos);
        assert!(cos >= 0.9999, "{}: cosine {cos}", item["text"]);
        assert!((ne - 1.0).abs() < 1e-5);
    }
    eprintln!("MiniLM vs reference: {} sentences, worst cosine {worst:.6}", items.len());
}

#[test]
fn empty_text_is_an_error() {
    let Some(enc) = encoder() else { return };
    assert!(matches!(enc.embed(&["  "]), Err(TextError::Empty)));
}

#[test]
fn missing_weights_say_how_to_fetch() {
    let e = MiniLm::load(std::path::Path::new("/nonexistent/dir"), &Device::flex())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("scripts/fetch-text-encoder.sh") && e.contains("model.safetensors"), "{e}");
}

/// The word-state input: the pooled embedding first (as `embed` gives it), then one unit row per
/// token up to the word count, zero rows after; a text's rows do not depend on its batch.
#[test]
fn word_states_follow_the_pooled_embedding() {
    let Some(enc) = encoder() else { return };
    let texts = ["a person walks forward, then sits down.", "jumps"];
    let (h, w) = (enc.dim(), 12);
    let pooled = enc.embed(&texts).unwrap();
    let full = enc.embed_words(&texts, w).unwrap();
    for (i, t) in texts.iter().enumerate() {
        assert_eq!(full[i].len(), h * (1 + w));
        assert_eq!(full[i][..h], pooled[i][..], "{t}");
        let tokens = enc.token_ids(t).unwrap().len();
        for (r, row) in full[i][h..].chunks(h).enumerate() {
            let norm = row.iter().map(|v| v * v).sum::<f32>().sqrt();
            let want = if r < tokens.min(w) { 1.0 } else { 0.0 };
            assert!((norm - want).abs() < 1e-5, "{t}: word {r} has norm {norm}");
        }
    }
    let alone = enc.embed_words(&texts[1..], w).unwrap();
    let e = alone[0].iter().zip(&full[1]).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    assert!(e < 1e-5, "batch padding changes a text's word states by {e}");
    // The two orders of a sequence differ in their word states far more than when pooled.
    let swapped =
        ["a person sits down, then walks forward.", "a person walks forward, then sits down."];
    let s = enc.embed_words(&swapped, w).unwrap();
    let cos = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
    let pooled_cos = cos(&s[0][..h], &s[1][..h]);
    let word_cos = (1..=4).map(|k| cos(&s[0][k * h..(k + 1) * h], &s[1][k * h..(k + 1) * h]));
    let worst = word_cos.fold(1.0f32, f32::min);
    eprintln!("swapped order: pooled cosine {pooled_cos:.3}, lowest of words 1-4 {worst:.3}");
    assert!(worst < pooled_cos - 0.1, "pooled {pooled_cos}, words {worst}");
}

#[test]
fn matches_hugging_face_ids() {
    let Some(tok) = tokenizer() else { return };
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/tokenizer_reference.json");
    let reference: serde_json::Value =
        serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    let items = reference["items"].as_array().unwrap();
    assert!(items.len() >= 20);
    for item in items {
        let text = item["text"].as_str().unwrap();
        let want: Vec<u32> =
            item["ids"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as u32).collect();
        assert_eq!(tok.encode(text), want, "{text:?}");
    }
    // The long text reaches the file's 128 ids, so truncation is exercised.
    assert!(items.iter().any(|i| i["ids"].as_array().unwrap().len() == 128));
}

#[test]
fn other_pipelines_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tokenizer.json");
    let json = r#"{"normalizer": {"type": "NFKC"}, "pre_tokenizer": {"type": "Whitespace"},
        "post_processor": {"type": "BertProcessing", "cls": ["[CLS]", 1], "sep": ["[SEP]", 2]},
        "model": {"type": "BPE", "vocab": {}, "merges": []}}"#;
    std::fs::write(&path, json).unwrap();
    let e = WordPiece::from_file(&path).err().unwrap();
    assert!(matches!(e, TextError::Bad { .. }));
    let msg = e.to_string();
    assert!(msg.contains("tokenizer.json") && msg.contains("NFKC"), "{msg}");
}

/// A hand-made BERT `tokenizer.json`.
fn hand_made() -> serde_json::Value {
    serde_json::from_str(
        r###"{"truncation": null, "padding": null, "added_tokens": [],
        "normalizer": {"type": "BertNormalizer", "clean_text": true, "handle_chinese_chars": true,
                       "strip_accents": null, "lowercase": true},
        "pre_tokenizer": {"type": "BertPreTokenizer"},
        "post_processor": {"type": "BertProcessing", "cls": ["[CLS]", 1], "sep": ["[SEP]", 2]},
        "model": {"type": "WordPiece", "unk_token": "[UNK]", "continuing_subword_prefix": "##",
                  "max_input_chars_per_word": 8,
                  "vocab": {"[UNK]": 0, "[CLS]": 1, "[SEP]": 2, "walk": 3, "##s": 4, "##ing": 5,
                            "w": 6, "##a": 7, "cafe": 8, ".": 9, "##lk": 10}}}"###,
    )
    .unwrap()
}

/// `json` written as a `tokenizer.json` in `dir`, then loaded.
fn load(dir: &std::path::Path, json: &serde_json::Value) -> Result<WordPiece, TextError> {
    let path = dir.join("tokenizer.json");
    std::fs::write(&path, json.to_string()).unwrap();
    WordPiece::from_file(&path)
}

/// The hand-made vocabulary: greedy longest match, `##` continuations, a word with a missing
/// piece as one unknown token, punctuation split off, accents stripped, the template around.
#[test]
fn word_pieces_by_hand() {
    let dir = tempfile::tempdir().unwrap();
    let tok = load(dir.path(), &hand_made()).unwrap();
    assert_eq!(tok.encode("Walks walking."), [1, 3, 4, 3, 5, 9, 2]);
    assert_eq!(tok.encode("wa"), [1, 6, 7, 2]);
    assert_eq!(tok.encode("CAFÉ walkx"), [1, 8, 0, 2]);
    assert_eq!(tok.encode("walkingss"), [1, 0, 2], "over max_input_chars_per_word");
}

/// Each part of a BERT file this tokenizer cannot follow is refused, naming the file and the part.
#[test]
fn unsupported_settings_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let cases: [(&str, serde_json::Value, &str); 5] = [
        ("/model/unk_token", "[NONE]".into(), "is not in the vocabulary"),
        ("/truncation", serde_json::json!({"max_length": 8, "direction": "Left"}), "direction"),
        (
            "/added_tokens",
            serde_json::json!([{"id": 1, "content": "[CLS]", "lstrip": true}]),
            "only plain raw-text tokens",
        ),
        (
            "/post_processor",
            serde_json::json!({"type": "TemplateProcessing", "special_tokens": {},
                "single": [{"Sequence": {"id": "A"}}, {"Sequence": {"id": "B"}}]}),
            "two sequences",
        ),
        (
            "/post_processor",
            serde_json::json!({"type": "TemplateProcessing", "special_tokens": {},
                "single": [{"SpecialToken": {"id": "[CLS]"}}, {"Sequence": {"id": "A"}}]}),
            "not among special_tokens",
        ),
    ];
    for (at, value, says) in cases {
        let mut json = hand_made();
        *json.pointer_mut(at).unwrap() = value;
        let msg = load(dir.path(), &json).err().unwrap().to_string();
        assert!(msg.contains("tokenizer.json") && msg.contains(says), "{at}: {msg}");
    }
}
