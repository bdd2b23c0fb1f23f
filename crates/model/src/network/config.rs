//! Network configuration: the paper's, and smaller ones for CPU work.

use burn::prelude::*;

/// DiffKFC denoiser hyper-parameters.
#[derive(Config, Debug, PartialEq)]
pub struct DiffKfcConfig {
    /// Motion feature width (HumanML3D 263, KIT-ML 251).
    #[config(default = 263)]
    pub feat_dim: usize,
    /// Width of the frozen text embedding (MiniLM: 384).
    #[config(default = 384)]
    pub text_dim: usize,
    #[config(default = 512)]
    pub d_model: usize,
    #[config(default = 8)]
    pub heads: usize,
    #[config(default = 1024)]
    pub ffn: usize,
    #[config(default = 8)]
    pub dec_layers: usize,
    /// Window size of each Dilated Mask Attention block; 0 stands for the whole sequence (N).
    #[config(default = "vec![2, 2, 4, 4, 6, 6, 8, 0]")]
    pub dma_sizes: Vec<usize>,
    #[config(default = 196)]
    pub max_frames: usize,
    #[config(default = 0.1)]
    pub dropout: f64,
    /// Root channels a keyframe may observe beside its features (place x, z and heading as
    /// sin, cos: our extension, see `diffkfc_data::postprocess::warp`); 0 = pose-only keyframes (the paper,
    /// and checkpoints made before root channels existed).
    #[config(default = 4)]
    pub root_channels: usize,
    /// Taps of a depthwise convolution over the frames in each decoder layer (odd; our
    /// extension, `crate::network::temporal`); 0 = none (the paper, and checkpoints made before it).
    #[config(default = 0)]
    pub temporal_kernel: usize,
    /// The decoder's frame tokens also read their own frame's keyframe values and masks (pose
    /// features and root channels) through a zero-initialised projection, beside the keyframe
    /// encoder's cross-attention (our extension, as CondMDI feeds observations with the noisy
    /// input); false for checkpoints made before it.
    #[config(default = false)]
    pub key_input: bool,
    /// Word states of the text encoder the decoder also attends to, beside the pooled sentence
    /// embedding (our extension, `crate::network::words`): the text input is then
    /// `text_dim * (1 + text_words)` wide (`TextEncoder::embed_words`), and longer captions keep
    /// their first `text_words` tokens. 0 = the pooled embedding alone (the paper, and
    /// checkpoints made before it).
    #[config(default = 0)]
    pub text_words: usize,
}

impl DiffKfcConfig {
    /// Values of one text input: the pooled embedding and `text_words` word states.
    pub fn text_width(&self) -> usize {
        self.text_dim * (1 + self.text_words)
    }

    /// The paper: d 512, 8 heads, FFN 1024, 8 decoder layers, 8 DMA blocks {2,2,4,4,6,6,8,N}.
    pub fn paper() -> Self {
        Self::new()
    }

    pub fn small() -> Self {
        Self::new()
            .with_d_model(256)
            .with_heads(4)
            .with_ffn(512)
            .with_dec_layers(4)
            .with_dma_sizes(vec![2, 4, 8, 0])
    }

    /// Between tiny and small, for training a better model on a CPU: d 128, 4 heads, FFN 256,
    /// 3 decoder layers, DMA {2,4,N}.
    pub fn mid() -> Self {
        Self::tiny().with_d_model(128).with_ffn(256).with_dec_layers(3)
    }

    /// Fast on a CPU: for tests, the quick start and smoke benchmarks.
    pub fn tiny() -> Self {
        Self::new()
            .with_d_model(64)
            .with_heads(4)
            .with_ffn(128)
            .with_dec_layers(2)
            .with_dma_sizes(vec![2, 4, 0])
    }

    /// The PyTorch timing reference's own small network (`../shared/bench`, `--config tiny`
    /// there): d 128, 4 heads, FFN 256, 4 decoder layers, DMA {2,4,8,N}; for like-for-like
    /// timings of a small model (`diffkfc bench --config torch-tiny --torch PY`).
    pub fn torch_tiny() -> Self {
        Self::small().with_d_model(128).with_ffn(256)
    }

    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "paper" => Some(Self::paper()),
            "small" => Some(Self::small()),
            "mid" => Some(Self::mid()),
            "tiny" => Some(Self::tiny()),
            "torch-tiny" => Some(Self::torch_tiny()),
            _ => None,
        }
    }
}
