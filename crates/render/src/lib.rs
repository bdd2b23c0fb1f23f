//! Pictures of motion: an animated GIF of a stick figure on a ground grid (root path traced,
//! frame counter, keyframes highlighted) and a PNG contact sheet of several clips, each drawn
//! as a strobe of poses. Pure Rust, a fixed 16-colour palette.

pub mod compare;
pub mod viewer;

use std::path::Path;

use diffkfc_data::motion::plausibility;
use diffkfc_data::motion::quat::Vec3;
use diffkfc_data::motion::representation::Joints;
use diffkfc_data::motion::skeleton::Skeleton;
use diffkfc_data::DataError;

/// Palette indices.
#[derive(Clone, Copy)]
#[repr(u8)]
enum C {
    Bg = 0,
    Grid,
    Path,
    PathDone,
    Left,
    Right,
    Spine,
    Key,
    KeyGhost,
    Text,
    Shadow,
    Fade1,
    Fade2,
    Fade3,
}

const PALETTE: [[u8; 3]; 16] = [
    [250, 250, 247],
    [215, 215, 210],
    [190, 190, 200],
    [110, 110, 130],
    [40, 90, 200],
    [210, 50, 50],
    [40, 40, 40],
    [255, 140, 0],
    [255, 205, 150],
    [20, 20, 20],
    [200, 200, 195],
    [205, 205, 215],
    [150, 150, 170],
    [90, 90, 110],
    [0, 0, 0],
    [0, 0, 0],
];

/// An indexed-colour canvas.
struct Canvas {
    w: usize,
    h: usize,
    px: Vec<u8>,
}

impl Canvas {
    fn new(w: usize, h: usize) -> Self {
        Canvas { w, h, px: vec![C::Bg as u8; w * h] }
    }

    fn dot(&mut self, x: f64, y: f64, r: f64, c: C) {
        let (x0, x1) = ((x - r).floor() as i64, (x + r).ceil() as i64);
        let (y0, y1) = ((y - r).floor() as i64, (y + r).ceil() as i64);
        for yy in y0..=y1 {
            for xx in x0..=x1 {
                if xx >= 0 && yy >= 0 && (xx as usize) < self.w && (yy as usize) < self.h {
                    let (dx, dy) = (xx as f64 - x, yy as f64 - y);
                    if dx * dx + dy * dy <= r * r + 0.25 {
                        self.px[yy as usize * self.w + xx as usize] = c as u8;
                    }
                }
            }
        }
    }

    fn line(&mut self, a: (f64, f64), b: (f64, f64), r: f64, c: C) {
        let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) * 2.0).ceil().max(1.0) as usize;
        for i in 0..=n {
            let t = i as f64 / n as f64;
            self.dot(a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t, r, c);
        }
    }

    /// Digits, '/', ' ' and 'f' in a 3x5 font, scaled by `s`.
    fn text(&mut self, x: usize, y: usize, s: usize, txt: &str) {
        const GLYPHS: [(char, [u8; 5]); 13] = [
            ('0', [7, 5, 5, 5, 7]),
            ('1', [2, 6, 2, 2, 7]),
            ('2', [7, 1, 7, 4, 7]),
            ('3', [7, 1, 7, 1, 7]),
            ('4', [5, 5, 7, 1, 1]),
            ('5', [7, 4, 7, 1, 7]),
            ('6', [7, 4, 7, 5, 7]),
            ('7', [7, 1, 2, 2, 2]),
            ('8', [7, 5, 7, 5, 7]),
            ('9', [7, 5, 7, 1, 7]),
            ('/', [1, 1, 2, 4, 4]),
            ('f', [3, 4, 6, 4, 4]),
            ('*', [0, 5, 2, 5, 0]),
        ];
        let mut cx = x;
        for ch in txt.chars() {
            if let Some((_, rows)) = GLYPHS.iter().find(|g| g.0 == ch) {
                for (ry, row) in rows.iter().enumerate() {
                    for rx in 0..3 {
                        if row >> (2 - rx) & 1 == 1 {
                            for dy in 0..s {
                                for dx in 0..s {
                                    let (px, py) = (cx + rx * s + dx, y + ry * s + dy);
                                    if px < self.w && py < self.h {
                                        self.px[py * self.w + px] = C::Text as u8;
                                    }
                                }
                            }
                        }
                    }
                }
            }
            cx += 4 * s;
        }
    }

    fn rgb(&self) -> Vec<u8> {
        self.px.iter().flat_map(|&i| PALETTE[i as usize]).collect()
    }
}

/// A fixed three-quarter view fitted to all frames of a motion.
struct Camera {
    centre: Vec3,
    scale: f64,
    w: f64,
    h: f64,
    az: (f64, f64),
    el: (f64, f64),
}

impl Camera {
    fn fit(j: &Joints, w: usize, h: usize) -> Camera {
        let az = (35f64.to_radians().sin(), 35f64.to_radians().cos());
        let el = (20f64.to_radians().sin(), 20f64.to_radians().cos());
        let mut cam = Camera { centre: [0.0; 3], scale: 1.0, w: w as f64, h: h as f64, az, el };
        let pts: Vec<Vec3> =
            j.iter().flatten().copied().chain(j.iter().map(|f| [f[0][0], 0.0, f[0][2]])).collect();
        let n = pts.len().max(1) as f64;
        cam.centre = [
            pts.iter().map(|p| p[0]).sum::<f64>() / n,
            0.8,
            pts.iter().map(|p| p[2]).sum::<f64>() / n,
        ];
        let (mut lo, mut hi) = ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN));
        for p in &pts {
            let q = cam.raw(*p);
            lo = (lo.0.min(q.0), lo.1.min(q.1));
            hi = (hi.0.max(q.0), hi.1.max(q.1));
        }
        let span = ((hi.0 - lo.0) / cam.w).max((hi.1 - lo.1) / cam.h).max(1e-3);
        cam.scale = 0.85 / span;
        // Recentre on the projected box.
        let mid = ((lo.0 + hi.0) / 2.0, (lo.1 + hi.1) / 2.0);
        let c0 = cam.raw(cam.centre);
        cam.centre_shift(mid.0 - c0.0, mid.1 - c0.1);
        cam
    }

    fn centre_shift(&mut self, dx: f64, dy: f64) {
        // Shift in projected units by moving the centre along the view's right and up axes.
        let right = [self.az.1, 0.0, -self.az.0];
        let up = [-self.el.0 * self.az.0, self.el.1, -self.el.0 * self.az.1];
        for k in 0..3 {
            self.centre[k] += right[k] * dx + up[k] * -dy;
        }
    }

    /// Orthographic coordinates (x right, y down) before scaling.
    fn raw(&self, p: Vec3) -> (f64, f64) {
        let d = [p[0] - self.centre[0], p[1] - self.centre[1], p[2] - self.centre[2]];
        let x = d[0] * self.az.1 - d[2] * self.az.0;
        let z = d[0] * self.az.0 + d[2] * self.az.1;
        let y = d[1] * self.el.1 - z * self.el.0;
        (x, -y)
    }

    fn project(&self, p: Vec3) -> (f64, f64) {
        let (x, y) = self.raw(p);
        (self.w / 2.0 + x * self.scale, self.h / 2.0 + y * self.scale)
    }
}

fn draw_grid(c: &mut Canvas, cam: &Camera, j: &Joints) {
    let xs = j.iter().map(|f| f[0][0]);
    let zs = j.iter().map(|f| f[0][2]);
    let (x0, x1) = xs.clone().fold((f64::MAX, f64::MIN), |a, v| (a.0.min(v), a.1.max(v)));
    let (z0, z1) = zs.clone().fold((f64::MAX, f64::MIN), |a, v| (a.0.min(v), a.1.max(v)));
    let (x0, x1, z0, z1) =
        ((x0 - 1.0).floor(), (x1 + 1.0).ceil(), (z0 - 1.0).floor(), (z1 + 1.0).ceil());
    let mut x = x0;
    while x <= x1 + 1e-9 {
        c.line(cam.project([x, 0.0, z0]), cam.project([x, 0.0, z1]), 0.5, C::Grid);
        x += 0.5;
    }
    let mut z = z0;
    while z <= z1 + 1e-9 {
        c.line(cam.project([x0, 0.0, z]), cam.project([x1, 0.0, z]), 0.5, C::Grid);
        z += 0.5;
    }
}

fn draw_figure(
    c: &mut Canvas,
    cam: &Camera,
    skel: &Skeleton,
    f: &[Vec3],
    colour: Option<C>,
    r: f64,
) {
    // Shadow of the root on the ground.
    c.dot(
        cam.project([f[0][0], 0.0, f[0][2]]).0,
        cam.project([f[0][0], 0.0, f[0][2]]).1,
        r + 1.5,
        C::Shadow,
    );
    for (k, chain) in skel.kinematic_chain.iter().enumerate() {
        let col = colour.unwrap_or(match k {
            0 | 3 => C::Right,
            1 | 4 => C::Left,
            _ => C::Spine,
        });
        for w in chain.windows(2) {
            c.line(cam.project(f[w[0]]), cam.project(f[w[1]]), r, col);
        }
    }
    // The head: the end of the spine chain.
    if let Some(&head) = skel.kinematic_chain.get(2).and_then(|c| c.last()) {
        let (x, y) = cam.project(f[head]);
        c.dot(x, y, r + 2.5, colour.unwrap_or(C::Spine));
    }
}

/// Size of GIF frames.
pub const GIF_SIZE: usize = 320;

/// An animated GIF of a motion; frames listed in `keyframes` are drawn highlighted and their
/// poses stay visible as ghosts.
/// Keyframes drawn as lasting ghosts only up to this many: denser keys (a body-part edit keys
/// every frame) would pile their ghosts into a wall; the figure itself still turns orange on
/// its keyed frames.
pub const MAX_GHOSTS: usize = 12;

pub fn gif(skel: &Skeleton, j: &Joints, keyframes: &[usize], path: &Path) -> Result<(), DataError> {
    plausibility::check_drawable(j).map_err(|e| e.in_file(path))?;
    let (w, h) = (GIF_SIZE, GIF_SIZE);
    let cam = Camera::fit(j, w, h);
    let mut base = Canvas::new(w, h);
    draw_grid(&mut base, &cam, j);
    let palette: Vec<u8> = PALETTE.iter().flatten().copied().collect();
    let mut bytes = Vec::new();
    {
        let io = |e: gif::EncodingError| {
            DataError::Invalid(format!("{}: GIF encoding failed: {e}", path.display()))
        };
        let mut enc = gif::Encoder::new(&mut bytes, w as u16, h as u16, &palette).map_err(io)?;
        enc.set_repeat(gif::Repeat::Infinite).map_err(io)?;
        for t in 0..j.len() {
            let mut c = Canvas { w, h, px: base.px.clone() };
            for (k, pair) in j.windows(2).enumerate() {
                let col = if k < t { C::PathDone } else { C::Path };
                c.line(
                    cam.project([pair[0][0][0], 0.0, pair[0][0][2]]),
                    cam.project([pair[1][0][0], 0.0, pair[1][0][2]]),
                    1.0,
                    col,
                );
            }
            for &k in keyframes
                .iter()
                .filter(|&&k| k < j.len() && k != t && keyframes.len() <= MAX_GHOSTS)
            {
                draw_figure(&mut c, &cam, skel, &j[k], Some(C::KeyGhost), 1.0);
            }
            let is_key = keyframes.contains(&t);
            draw_figure(&mut c, &cam, skel, &j[t], if is_key { Some(C::Key) } else { None }, 2.0);
            c.text(8, 8, 2, &format!("f{}/{}{}", t, j.len() - 1, if is_key { " *" } else { "" }));
            let mut frame = gif::Frame::from_indexed_pixels(w as u16, h as u16, c.px, None);
            frame.delay = (100.0 / skel.fps).round() as u16;
            enc.write_frame(&frame).map_err(io)?;
        }
    }
    diffkfc_data::write_atomic(path, &bytes)
}

/// A contact sheet: one cell per clip, each a strobe of `poses` poses from light to dark,
/// keyframes (if any) in orange; `cols` cells per row.
pub fn sheet(
    skel: &Skeleton,
    clips: &[(Joints, Vec<usize>)],
    cols: usize,
    cell: usize,
    path: &Path,
) -> Result<(), DataError> {
    for (j, _) in clips {
        plausibility::check_drawable(j).map_err(|e| e.in_file(path))?;
    }
    let cols = cols.max(1).min(clips.len().max(1));
    let rows = clips.len().div_ceil(cols).max(1);
    let (w, h) = (cols * cell, rows * cell);
    let mut out = vec![0u8; w * h * 3];
    for (i, (j, keys)) in clips.iter().enumerate() {
        let mut c = Canvas::new(cell, cell);
        if !j.is_empty() {
            let cam = Camera::fit(j, cell, cell);
            draw_grid(&mut c, &cam, j);
            for pair in j.windows(2) {
                c.line(
                    cam.project([pair[0][0][0], 0.0, pair[0][0][2]]),
                    cam.project([pair[1][0][0], 0.0, pair[1][0][2]]),
                    1.0,
                    C::Path,
                );
            }
            let n = 6.min(j.len());
            let fades = [C::Fade1, C::Fade2, C::Fade3, C::Fade3, C::Spine, C::Spine];
            for s in 0..n {
                let t = if n == 1 { 0 } else { s * (j.len() - 1) / (n - 1) };
                draw_figure(&mut c, &cam, skel, &j[t], Some(fades[s * fades.len() / n]), 1.2);
            }
            for &k in keys.iter().filter(|&&k| k < j.len() && keys.len() <= MAX_GHOSTS) {
                draw_figure(&mut c, &cam, skel, &j[k], Some(C::Key), 1.4);
            }
            c.text(6, 6, 2, &format!("{}", i));
        }
        let rgb = c.rgb();
        let (ox, oy) = ((i % cols) * cell, (i / cols) * cell);
        for y in 0..cell {
            let dst = ((oy + y) * w + ox) * 3;
            out[dst..dst + cell * 3].copy_from_slice(&rgb[y * cell * 3..(y + 1) * cell * 3]);
        }
    }
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, w as u32, h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let err = |e: png::EncodingError| {
            DataError::Invalid(format!("{}: PNG encoding failed: {e}", path.display()))
        };
        enc.write_header().map_err(err)?.write_image_data(&out).map_err(err)?;
    }
    diffkfc_data::write_atomic(path, &bytes)
}
