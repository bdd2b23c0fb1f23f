//! The evaluation protocol of the paper: for every replication, draw test items (shuffled with
//! the replication's seed, ground-truth lengths, one random caption each) and keyframes as in
//! training (same seed for every setting, so settings are compared on the same keyframes); for
//! every setting (keyframe mode, transition guidance, keyframe rate) generate and measure.
//! The "Real motion" rows measure the real test motions the same way.

use std::collections::BTreeMap;

use diffkfc_data::dataset::cache::PackedSplit;
use diffkfc_data::dataset::Dataset;
use diffkfc_data::keyframes::{self, Strategy};
use diffkfc_data::motion::plausibility::{foot_skating_ratio, penetration};
use diffkfc_data::motion::representation::{recover_from_ric, Joints};
use diffkfc_data::motion::root_key::{self, RootKey};
use diffkfc_data::motion::skeleton::Skeleton;
use diffkfc_data::rng::Rng;
use diffkfc_model::diffusion::scheduler::Sampler;
use diffkfc_model::sampling::fit::{Fit, KeyframeFit};
use diffkfc_model::sampling::guidance::Guidance;
use diffkfc_model::sampling::pipeline::{Generator, KeyedItem};
use diffkfc_model::sampling::place::PlaceGuidance;
use diffkfc_model::sampling::sampler::{self, TgMode};
use diffkfc_model::text::cache::EmbeddingCache;

use crate::evaluator::{eval_length, TextMotionEvaluator};
use crate::gait;
use crate::keyframe_metrics::{displacement_error, k_err_global, k_err_local, k_trans};
pub use crate::rows::{Rows, Setting};
use crate::text_motion::{diversity, finite, multimodality, r_precision_of, text_ranks, Gaussian};

/// Generations per text and pairs per text of MultiModality; pairs of Diversity; R-precision
/// batch; K-TranS half window.
pub const MM_GENERATIONS: usize = 30;
pub const MM_PAIRS: usize = 10;
pub const DIVERSITY_PAIRS: usize = 300;
pub const R_BATCH: usize = 32;
pub const K_TRANS_WINDOW: usize = 2;

#[derive(Clone, Debug)]
pub struct ProtocolOptions {
    pub replications: usize,
    pub num_items: usize,
    pub samples_for_ade: usize,
    /// Texts for MultiModality (0 = off).
    pub multimodality: usize,
    pub sampler: Sampler,
    pub kf_guidance: f64,
    /// Text guidance scale (1 = off; `sampler::Options::text_guidance`).
    pub text_guidance: f64,
    /// How transition guidance takes its gradient (exact: through the denoiser, which must be
    /// on an autodiff device).
    pub tg_mode: TgMode,
    /// How generated motions are made to meet their keyframes after the last step, and whether
    /// their planted feet are locked.
    pub fit: Fit,
    /// Keyframes observe their root place and heading as well as their pose.
    pub root_keys: bool,
    /// Place guidance strength (0 = off).
    pub place_guidance: f64,
    pub strategy: Strategy,
    /// Generated motions per denoiser batch (keyframe guidance doubles it).
    pub batch: usize,
    pub seed: u64,
}

/// Per metric, its value in each replication (metrics undefined for a row are absent).
pub type Values = BTreeMap<&'static str, Vec<f64>>;

/// A row of results: a setting, or the real motions at a keyframe rate (`setting: None`).
#[derive(Clone, Debug)]
pub struct RowResult {
    pub setting: Option<Setting>,
    pub rate: f64,
    pub values: Values,
    /// Per replication, each item's value of the measures in [`PER_ITEM`] (generated rows), so
    /// two runs on the same items compare item by item.
    pub per_item: BTreeMap<&'static str, Vec<Vec<f64>>>,
}

/// The measures kept per item as well as on average.
pub const PER_ITEM: [&str; 1] = ["foot_skate"];

/// Per-item key of each motion's text rank (`text_motion::text_ranks`): which captions a
/// model fails, read beside `Protocol::captions`.
pub const TEXT_RANK: &str = "text_rank";

pub struct Protocol<'a> {
    /// The model, its schedule and the normalisation it was trained with.
    pub gen: Generator<'a>,
    pub ds: &'a Dataset,
    pub split: &'a PackedSplit,
    /// The model's text inputs (with its `model.text_words` word states).
    pub text: &'a EmbeddingCache,
    pub evaluator: &'a dyn TextMotionEvaluator,
    pub opts: ProtocolOptions,
}

struct Item<'s> {
    len: usize,
    caption: String,
    /// Raw features [len, D].
    feats: &'s [f32],
    joints: Joints,
}

fn joints_of(ds: &Dataset, f: &[f32]) -> Joints {
    recover_from_ric(ds.skeleton, &f.iter().map(|&v| v as f64).collect::<Vec<_>>())
}

/// The plausibility and gait numbers of one motion that every row reports.
fn motion_measures(skel: &Skeleton, j: &Joints) -> [(&'static str, f64); 4] {
    [
        ("foot_skate", foot_skating_ratio(skel, j)),
        ("penetrate", penetration(skel, j)),
        ("planted", gait::planted_share(skel, j)),
        ("stride", gait::stride_amplitude(skel, j)),
    ]
}

fn mean(xs: &[f64]) -> Option<f64> {
    (!xs.is_empty()).then(|| xs.iter().sum::<f64>() / xs.len() as f64)
}

impl Protocol<'_> {
    /// A replication's draw: each item's index in the split and the caption it is given.
    fn draw(&self, rep: usize) -> Vec<(usize, String)> {
        let mut order: Vec<usize> = (0..self.split.items.len()).collect();
        Rng::derive(self.opts.seed, 1, rep as u64).shuffle(&mut order);
        order.truncate(self.opts.num_items);
        order
            .into_iter()
            .enumerate()
            .map(|(pos, i)| {
                let caption = Rng::derive(self.opts.seed, 2 + (rep as u64) * 16, pos as u64)
                    .pick(&self.split.items[i].captions)
                    .clone();
                (i, caption)
            })
            .collect()
    }

    fn items(&self, rep: usize) -> Vec<Item<'_>> {
        let d = self.ds.dim();
        self.draw(rep)
            .into_iter()
            .map(|(i, caption)| {
                let len = eval_length(self.split.items[i].len);
                let feats = &self.split.item_frames(i)[..len * d];
                Item { len, caption, feats, joints: joints_of(self.ds, feats) }
            })
            .collect()
    }

    /// Per replication, each item's clip name and caption, in the order of the per-item values.
    pub fn captions(&self) -> Vec<Vec<(String, String)>> {
        (0..self.opts.replications)
            .map(|rep| {
                let items = self.draw(rep).into_iter();
                items.map(|(i, c)| (self.split.items[i].clip.clone(), c)).collect()
            })
            .collect()
    }

    /// Keyframes of every item at `rate`: the same for every setting of a replication.
    fn keys(&self, rep: usize, items: &[Item], rate: f64) -> Vec<Vec<usize>> {
        let d = self.ds.dim();
        let stream = 3 + (rep as u64) * 16;
        items
            .iter()
            .enumerate()
            .map(|(p, it)| {
                keyframes::select(
                    self.opts.strategy,
                    it.len,
                    rate,
                    it.feats,
                    d,
                    &mut Rng::derive(self.opts.seed, stream, p as u64),
                )
            })
            .collect()
    }

    /// Denoising steps (sampler calls) one generation of `rows` motions costs.
    fn steps_for(&self, rows: usize) -> usize {
        // The track fit denoises keyed motions twice (an upper bound: text-only rows once).
        let stages = if self.opts.fit.keyframes == KeyframeFit::Track && self.opts.root_keys {
            2
        } else {
            1
        };
        stages
            * rows.div_ceil(self.opts.batch.max(1))
            * diffkfc_model::diffusion::scheduler::timesteps(self.gen.schedule, self.opts.sampler)
                .len()
    }

    /// Denoising steps the whole run takes (for the progress bar and the estimate).
    pub fn planned_steps(&self, settings: &[Setting]) -> usize {
        let n = self.opts.num_items.min(self.split.items.len());
        let mm = if self.opts.multimodality > 0 {
            self.steps_for(self.opts.multimodality.min(n) * MM_GENERATIONS)
        } else {
            0
        };
        let proposals = settings.iter().filter(|s| s.suggested).count() * self.steps_for(n);
        self.opts.replications
            * (settings.len() * (self.steps_for(n * self.opts.samples_for_ade.max(1)) + mm)
                + proposals)
    }

    /// Guidance branches of generating `s` (each multiplies the denoiser batch).
    fn branches(&self, s: &Setting) -> usize {
        let o = &self.opts;
        Guidance::new(o.kf_guidance, o.text_guidance, s.rate > 0.0, s.inpaint).branches()
    }

    /// Generation jobs (item, sample) in denoiser batches, sorted by length to limit padding.
    fn batches(&self, items: &[Item], k: usize) -> Vec<Vec<(usize, usize)>> {
        let mut jobs: Vec<(usize, usize)> =
            (0..items.len()).flat_map(|p| (0..k).map(move |j| (p, j))).collect();
        jobs.sort_by_key(|&(p, _)| items[p].len);
        jobs.chunks(self.opts.batch.max(1)).map(<[_]>::to_vec).collect()
    }

    /// Work of one generation in frame-rows per denoising step (padded batch x frames, times
    /// the guidance branches), summed over batches.
    fn units(&self, items: &[Item], k: usize, s: &Setting) -> f64 {
        let per_row = self.branches(s) as f64;
        self.batches(items, k)
            .iter()
            .map(|c| {
                per_row * (c.len() * c.iter().map(|&(p, _)| items[p].len).max().unwrap_or(0)) as f64
            })
            .sum()
    }

    /// Estimated seconds of the whole run: its work (on replication 0's items) times the
    /// measured cost of a frame-row, from a 2-step guided generation of one batch (encoder
    /// included, so a slight overestimate).
    pub fn estimate_seconds(&self, settings: &[Setting]) -> f64 {
        let probe = Protocol {
            opts: ProtocolOptions {
                sampler: Sampler::Ddim(2),
                num_items: self.opts.batch,
                ..self.opts.clone()
            },
            ..*self
        };
        let items = probe.items(0);
        let s = Setting {
            name: String::new(),
            rate: settings.iter().map(|s| s.rate).fold(0.05, f64::max),
            inpaint: false,
            transition: 0.0,
            suggested: false,
        };
        let keys = probe.keys(0, &items, s.rate);
        let t0 = std::time::Instant::now();
        probe.generate(&items, &keys, &s, 1, 0, &mut || {});
        let per_unit = t0.elapsed().as_secs_f64() / 2.0 / probe.units(&items, 1, &s).max(1.0);
        let items = self.items(0);
        let steps =
            diffkfc_model::diffusion::scheduler::timesteps(self.gen.schedule, self.opts.sampler)
                .len() as f64;
        let mm = self.opts.multimodality.min(items.len());
        let text_only = Setting { rate: 0.0, ..s.clone() };
        let proposal =
            |s: &Setting| if s.suggested { self.units(&items, 1, &text_only) } else { 0.0 };
        let work: f64 = settings
            .iter()
            .map(|s| {
                proposal(s)
                    + self.units(&items, self.opts.samples_for_ade.max(1), s)
                    + if mm > 0 { self.units(&items[..mm], MM_GENERATIONS, s) } else { 0.0 }
            })
            .sum();
        work * steps * per_unit * self.opts.replications as f64
    }

    /// `k` samples per item (raw features [len, D]), in batches sorted by length.
    fn generate(
        &self,
        items: &[Item],
        keys: &[Vec<usize>],
        s: &Setting,
        k: usize,
        seed: u64,
        tick: &mut dyn FnMut(),
    ) -> Vec<Vec<Vec<f32>>> {
        let all_dims = keyframes::dim_mask(self.ds.skeleton, None);
        let mut out: Vec<Vec<Vec<f32>>> = items.iter().map(|_| vec![Vec::new(); k]).collect();
        for (c, chunk) in self.batches(items, k).iter().enumerate() {
            let n = chunk.iter().map(|&(p, _)| items[p].len).max().unwrap_or(1);
            let masks: Vec<Vec<f32>> = chunk
                .iter()
                .map(|&(p, _)| keyframes::frame_mask(items[p].len, &keys[p], &all_dims))
                .collect();
            let roots: Vec<Vec<RootKey>> =
                chunk.iter().map(|&(p, _)| self.root_keys(&items[p], &keys[p])).collect();
            let keyed: Vec<KeyedItem> = chunk
                .iter()
                .zip(masks.iter().zip(&roots))
                .map(|(&(p, _), (mask, root))| KeyedItem {
                    text: self
                        .text
                        .get(&items[p].caption)
                        .expect("captions of the split are embedded"),
                    length: items[p].len,
                    values: items[p].feats,
                    mask,
                    root,
                })
                .collect();
            let req = self.gen.request(n, &keyed);
            let opts = self.sampler_options(s, Rng::derive(seed, 7, c as u64).next_u64());
            let fitted = self.gen.generate(&req, &opts, self.opts.fit, |_, _| tick());
            for (f, &(p, j)) in fitted.into_iter().zip(chunk) {
                out[p][j] = f.features;
            }
        }
        out
    }

    /// The root keys of `item` at `keys` (none unless the protocol keys the root).
    fn root_keys(&self, item: &Item, keys: &[usize]) -> Vec<RootKey> {
        let mut root = vec![RootKey::default(); item.len];
        if self.opts.root_keys {
            let traj = root_key::root_trajectory(item.feats, self.ds.dim());
            keys.iter().for_each(|&f| root[f] = traj[f]);
        }
        root
    }

    /// The sampler's options for setting `s` with this seed.
    fn sampler_options(&self, s: &Setting, seed: u64) -> sampler::Options {
        let o = &self.opts;
        sampler::Options {
            sampler: o.sampler,
            kf_guidance: o.kf_guidance,
            text_guidance: o.text_guidance,
            transition: s.transition,
            seed,
            tg_mode: o.tg_mode,
            inpaint: s.inpaint,
            place: PlaceGuidance::of_strength(o.place_guidance, self.gen.mean, self.gen.std),
            ..Default::default()
        }
    }

    /// Text-motion metrics of motions paired with the replication's caption embeddings; returns
    /// each item's text rank (`text_ranks`; NaN outside R-precision's full batches).
    fn text_motion(
        &self,
        reference: &Gaussian,
        texts: &[Vec<f64>],
        motions: &[Vec<f64>],
        seed: u64,
        v: &mut Values,
    ) -> Vec<f64> {
        let ranks = text_ranks(texts, motions, R_BATCH);
        let ([r1, r2, r3], mm) = r_precision_of(&ranks, texts, motions);
        let (fid_mean, fid_cov) = reference.fid_terms_to(motions);
        let pairs = [
            ("fid", fid_mean + fid_cov),
            ("fid_mean_term", fid_mean),
            ("r_top1", r1),
            ("r_top2", r2),
            ("r_top3", r3),
            ("mm_dist", mm),
            ("diversity", diversity(motions, DIVERSITY_PAIRS, seed)),
        ];
        for (k, x) in pairs {
            v.entry(k).or_default().push(x);
        }
        ranks.into_iter().map(|r| r.map_or(f64::NAN, |r| r as f64)).collect()
    }

    /// Run every setting for every replication. `reference`: evaluator statistics of the real
    /// test motions that FID compares against.
    pub fn run(
        &self,
        settings: &[Setting],
        reference: &Gaussian,
        tick: &mut dyn FnMut(),
    ) -> crate::error::Result<Vec<RowResult>> {
        let mut rates: Vec<f64> = settings.iter().map(|s| s.rate).collect();
        rates.sort_by(f64::total_cmp);
        rates.dedup();
        let mut real: Vec<RowResult> = rates
            .iter()
            .map(|&rate| RowResult {
                setting: None,
                rate,
                values: Values::new(),
                per_item: BTreeMap::new(),
            })
            .collect();
        let mut rows: Vec<RowResult> = settings
            .iter()
            .map(|s| RowResult {
                setting: Some(s.clone()),
                rate: s.rate,
                values: Values::new(),
                per_item: BTreeMap::new(),
            })
            .collect();
        for rep in 0..self.opts.replications {
            let items = self.items(rep);
            let captions: Vec<&str> = items.iter().map(|it| it.caption.as_str()).collect();
            let texts = finite(self.evaluator.embed_texts(&captions)?, "the text embeddings")?;
            let rep_seed = Rng::derive(self.opts.seed, 5, rep as u64).next_u64();
            self.real_rows(rep, &items, &texts, reference, rep_seed, &mut real)?;
            for row in rows.iter_mut() {
                self.generated_row(rep, &items, &texts, reference, rep_seed, row, tick)?;
            }
        }
        real.extend(rows);
        Ok(real)
    }

    /// One replication's real-motion rows (one per keyframe rate): the text-motion metrics and
    /// foot skating of the real motions (the same at every rate) and K-TranS at each rate's keys.
    fn real_rows(
        &self,
        rep: usize,
        items: &[Item],
        texts: &[Vec<f64>],
        reference: &Gaussian,
        rep_seed: u64,
        real: &mut [RowResult],
    ) -> crate::error::Result<()> {
        let real_m = finite(
            self.evaluator.embed_motions(&items.iter().map(|it| it.feats).collect::<Vec<_>>()),
            "the real motions' embeddings",
        )?;
        let mut shared = Values::new();
        let ranks = self.text_motion(reference, texts, &real_m, rep_seed, &mut shared);
        let skel = self.ds.skeleton;
        let per: Vec<_> = items.iter().map(|it| motion_measures(skel, &it.joints)).collect();
        for k in 0..per.first().map_or(0, |m| m.len()) {
            if let Some(x) = mean(&per.iter().map(|m| m[k].1).collect::<Vec<_>>()) {
                shared.insert(per[0][k].0, vec![x]);
            }
        }
        for row in real.iter_mut() {
            for (k, x) in &shared {
                row.values.entry(k).or_default().extend(x);
            }
            row.per_item.entry(TEXT_RANK).or_default().push(ranks.clone());
            let keys = self.keys(rep, items, row.rate);
            let kt: Vec<f64> = items
                .iter()
                .zip(&keys)
                .filter_map(|(it, k)| k_trans(&it.joints, k, K_TRANS_WINDOW))
                .collect();
            row.values.entry("k_trans").or_default().extend(mean(&kt));
        }
        Ok(())
    }

    /// One replication of a generated row: its keys (drawn as in training, or the MDO frames of
    /// a text-only proposal for the two-stage row), the generations, every metric.
    #[allow(clippy::too_many_arguments)]
    fn generated_row(
        &self,
        rep: usize,
        items: &[Item],
        texts: &[Vec<f64>],
        reference: &Gaussian,
        rep_seed: u64,
        row: &mut RowResult,
        tick: &mut dyn FnMut(),
    ) -> crate::error::Result<()> {
        let s = row.setting.clone().expect("generated row");
        // Two stages: a text-only proposal per item, whose MDO frames are the keys.
        let proposals: Vec<Vec<f32>> = if s.suggested {
            let none: Vec<Vec<usize>> = vec![Vec::new(); items.len()];
            let text_only = Setting { rate: 0.0, suggested: false, ..s.clone() };
            self.generate(items, &none, &text_only, 1, rep_seed ^ 0x5347, tick)
                .into_iter()
                .map(|mut g| g.swap_remove(0))
                .collect()
        } else {
            Vec::new()
        };
        let staged: Vec<Item> = items
            .iter()
            .zip(&proposals)
            .map(|(it, f)| Item {
                len: it.len,
                caption: it.caption.clone(),
                feats: f,
                joints: joints_of(self.ds, f),
            })
            .collect();
        let targets = if s.suggested { &staged[..] } else { items };
        let keys = if s.suggested {
            self.mdo_keys(targets, s.rate)
        } else {
            self.keys(rep, items, s.rate)
        };
        let k = self.opts.samples_for_ade.max(1);
        let gens = self.generate(targets, &keys, &s, k, rep_seed, tick);
        for (name, xs) in self.keyframe_scores(targets, &keys, &gens) {
            row.values.entry(name).or_default().extend(mean(&xs));
            if PER_ITEM.contains(&name) {
                row.per_item.entry(name).or_default().push(xs);
            }
        }
        let first: Vec<&[f32]> = gens.iter().map(|g| g[0].as_slice()).collect();
        let motions =
            finite(self.evaluator.embed_motions(&first), "the generated motions' embeddings")?;
        let ranks = self.text_motion(reference, texts, &motions, rep_seed, &mut row.values);
        row.per_item.entry(TEXT_RANK).or_default().push(ranks);
        if self.opts.multimodality > 0 {
            let mm = self.multimodality_of(targets, &keys, &s, rep_seed, tick)?;
            row.values.entry("multimodality").or_default().push(mm);
        }
        Ok(())
    }

    /// The MDO frames of each target at `rate` (the two-stage row's keys).
    fn mdo_keys(&self, targets: &[Item], rate: f64) -> Vec<Vec<usize>> {
        let d = self.ds.dim();
        let select =
            |t: &Item| keyframes::select(Strategy::Mdo, t.len, rate, t.feats, d, &mut Rng::new(0));
        targets.iter().map(select).collect()
    }

    /// MultiModality over the first --multimodality targets: `MM_GENERATIONS` generations of
    /// each, embedded, `MM_PAIRS` pairs apart.
    fn multimodality_of(
        &self,
        targets: &[Item],
        keys: &[Vec<usize>],
        s: &Setting,
        rep_seed: u64,
        tick: &mut dyn FnMut(),
    ) -> crate::error::Result<f64> {
        let m = self.opts.multimodality.min(targets.len());
        let groups =
            self.generate(&targets[..m], &keys[..m], s, MM_GENERATIONS, rep_seed ^ 0x4d4d, tick);
        let emb: Vec<Vec<Vec<f64>>> = groups
            .iter()
            .map(|g| {
                let g: Vec<&[f32]> = g.iter().map(Vec::as_slice).collect();
                finite(self.evaluator.embed_motions(&g), "the MultiModality embeddings")
            })
            .collect::<crate::error::Result<_>>()?;
        Ok(multimodality(&emb, MM_PAIRS, rep_seed))
    }

    /// Per item, the keyframe metrics of its generations `gens` against its target: ADE (the
    /// best of the samples), K-Err, K-TranS (and the target's), foot skating.
    fn keyframe_scores(
        &self,
        targets: &[Item],
        keys: &[Vec<usize>],
        gens: &[Vec<Vec<f32>>],
    ) -> BTreeMap<&'static str, Vec<f64>> {
        let skel = self.ds.skeleton;
        let all_joints: Vec<usize> = (0..skel.num_joints()).collect();
        let k = self.opts.samples_for_ade.max(1);
        let mut per: BTreeMap<&'static str, Vec<f64>> = BTreeMap::new();
        for ((it, key), samples) in targets.iter().zip(keys).zip(gens) {
            let joints: Vec<Joints> = samples.iter().map(|f| joints_of(self.ds, f)).collect();
            let ade = joints
                .iter()
                .filter_map(|j| displacement_error(j, &it.joints, key))
                .fold(f64::INFINITY, f64::min);
            let avg =
                |f: &dyn Fn(usize) -> Option<f64>| mean(&(0..k).filter_map(f).collect::<Vec<_>>());
            let entries = [
                ("ade", ade.is_finite().then_some(ade)),
                ("k_err", avg(&|j| k_err_global(&joints[j], &it.joints, key, &all_joints))),
                (
                    "k_err_local",
                    avg(&|j| k_err_local(skel, &samples[j], it.feats, key, &all_joints)),
                ),
                ("k_trans", avg(&|j| k_trans(&joints[j], key, K_TRANS_WINDOW))),
                ("k_trans_real", k_trans(&it.joints, key, K_TRANS_WINDOW)),
            ];
            for (name, x) in entries {
                if let Some(x) = x {
                    per.entry(name).or_default().push(x);
                }
            }
            let measures: Vec<_> = joints.iter().map(|j| motion_measures(skel, j)).collect();
            for k in 0..measures.first().map_or(0, |m| m.len()) {
                if let Some(x) = mean(&measures.iter().map(|m| m[k].1).collect::<Vec<_>>()) {
                    per.entry(measures[0][k].0).or_default().push(x);
                }
            }
        }
        per
    }
}
