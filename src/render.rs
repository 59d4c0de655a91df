//! Pictures: a small CPU rasteriser for meshes shaded by a per-vertex value (z-buffer,
//! orthographic camera, Gouraud interpolation, 2x2 supersampling), and the side-by-side
//! `result | truth | error` picture with a labelled colour bar that every kernel's
//! `--reference` run writes. It makes the PNGs the CLI writes; it is not a kernel.

use crate::error::{Error, Result};
use crate::io::FloatImage;
use glam::{Vec2, Vec3};
use std::path::Path;

/// Camera and image settings.
#[derive(Clone, Copy, Debug)]
pub struct View {
    /// Direction from the camera towards the scene.
    pub direction: Vec3,
    pub up: Vec3,
    pub width: u32,
    pub height: u32,
}

impl Default for View {
    fn default() -> Self {
        View {
            direction: Vec3::new(-0.85, -0.35, -0.75).normalize(),
            up: Vec3::Y,
            width: 640,
            height: 480,
        }
    }
}

/// Per-pixel values of a rendered mesh: at each pixel the mean of the interpolated
/// per-vertex value over the covered subsamples (NaN where nothing is covered), and the
/// fraction of subsamples covered.
#[derive(Clone, Debug)]
pub struct ValueImage {
    pub width: u32,
    pub height: u32,
    pub value: Vec<f32>,
    pub coverage: Vec<f32>,
}

impl ValueImage {
    /// As a linear float image: R = G = B = value (0 where uncovered), A = coverage.
    pub fn to_float(&self) -> FloatImage {
        FloatImage {
            width: self.width,
            height: self.height,
            pixels: self
                .value
                .iter()
                .zip(&self.coverage)
                .map(|(&v, &c)| {
                    let v = if v.is_finite() { v } else { 0.0 };
                    [v, v, v, c]
                })
                .collect(),
        }
    }
}

/// An RGB8 picture, rows top to bottom.
#[derive(Clone, Debug, PartialEq)]
pub struct Picture {
    pub width: u32,
    pub height: u32,
    /// `width * height * 3` bytes.
    pub rgb: Vec<u8>,
}

/// Rasterises triangles carrying a per-vertex `value` (z-buffer, orthographic camera,
/// Gouraud interpolation, 2x2 supersampling). The camera frames `frame_points` (e.g. the
/// bounds of a whole animation) and `positions`, so pictures of several frames line up.
pub fn rasterize(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    value: &[f32],
    frame_points: &[Vec3],
    view: &View,
) -> ValueImage {
    let ss = 2u32;
    let (w, h) = (view.width * ss, view.height * ss);
    let fwd = view.direction.normalize();
    let right = fwd.cross(view.up).try_normalize().unwrap_or(Vec3::X);
    let up = right.cross(fwd);
    let project = |p: Vec3| Vec3::new(p.dot(right), p.dot(up), p.dot(fwd));
    let (mut lo, mut hi) = (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY));
    for p in frame_points.iter().chain(positions) {
        let q = project(*p);
        lo = lo.min(q.truncate());
        hi = hi.max(q.truncate());
    }
    let size = (hi - lo).max(Vec2::splat(1e-6));
    let scale = 0.9 * (w as f32 / size.x).min(h as f32 / size.y);
    let centre = (lo + hi) * 0.5;
    let to_screen = |p: Vec3| {
        let q = project(p);
        Vec3::new(
            (q.x - centre.x) * scale + w as f32 * 0.5,
            h as f32 * 0.5 - (q.y - centre.y) * scale,
            q.z,
        )
    };
    let screen: Vec<Vec3> = positions.iter().map(|p| to_screen(*p)).collect();
    let mut depth = vec![f32::INFINITY; (w * h) as usize];
    let mut sample = vec![f32::NAN; (w * h) as usize];
    for t in triangles {
        let Some([a, b, c]) = t
            .iter()
            .map(|&i| screen.get(i as usize).copied())
            .collect::<Option<Vec<Vec3>>>()
            .and_then(|v| <[Vec3; 3]>::try_from(v).ok())
        else {
            continue;
        };
        let [va, vb, vc] = t.map(|i| value.get(i as usize).copied().unwrap_or(0.0));
        let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
        if area.abs() < 1e-12 {
            continue;
        }
        let x0 = a.x.min(b.x).min(c.x).floor().max(0.0) as u32;
        let x1 = a.x.max(b.x).max(c.x).ceil().min(w as f32 - 1.0) as u32;
        let y0 = a.y.min(b.y).min(c.y).floor().max(0.0) as u32;
        let y1 = a.y.max(b.y).max(c.y).ceil().min(h as f32 - 1.0) as u32;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let w0 = ((b.x - px) * (c.y - py) - (b.y - py) * (c.x - px)) / area;
                let w1 = ((c.x - px) * (a.y - py) - (c.y - py) * (a.x - px)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * a.z + w1 * b.z + w2 * c.z;
                let i = (y * w + x) as usize;
                if z < depth[i] {
                    depth[i] = z;
                    sample[i] = w0 * va + w1 * vb + w2 * vc;
                }
            }
        }
    }
    let n = (view.width * view.height) as usize;
    let (mut value, mut coverage) = (vec![f32::NAN; n], vec![0.0; n]);
    for y in 0..view.height {
        for x in 0..view.width {
            let (mut sum, mut count) = (0.0, 0u32);
            for sy in 0..ss {
                for sx in 0..ss {
                    let v = sample[((y * ss + sy) * w + x * ss + sx) as usize];
                    if !v.is_nan() {
                        sum += v;
                        count += 1;
                    }
                }
            }
            let o = (y * view.width + x) as usize;
            if count > 0 {
                value[o] = sum / count as f32;
            }
            coverage[o] = count as f32 / (ss * ss) as f32;
        }
    }
    ValueImage {
        width: view.width,
        height: view.height,
        value,
        coverage,
    }
}

/// The background of pictures at row `y` of `height` (a dark blue-grey gradient).
fn background(y: u32, height: u32) -> Vec3 {
    let g = 0.16 + 0.08 * (y as f32 / height.max(1) as f32);
    Vec3::new(g * 0.8, g * 0.9, g * 1.1)
}

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
}

/// Shades a value image: 0 black .. 1 white (slightly warm), linear, over the background.
pub fn shade(img: &ValueImage) -> Picture {
    let mut rgb = vec![0u8; (img.width * img.height * 3) as usize];
    for y in 0..img.height {
        for x in 0..img.width {
            let o = (y * img.width + x) as usize;
            let c = img.coverage[o];
            let v = if c > 0.0 {
                img.value[o].clamp(0.0, 1.0)
            } else {
                0.0
            };
            let colour = Vec3::new(1.0, 0.96, 0.9) * v * c + background(y, img.height) * (1.0 - c);
            for k in 0..3 {
                // Shown linearly, as ambient-occlusion maps conventionally are (a display
                // gamma would wash out everything above 0.8).
                rgb[o * 3 + k] = to_u8(colour[k]);
            }
        }
    }
    Picture {
        width: img.width,
        height: img.height,
        rgb,
    }
}

/// Shades three value images (linear RGB radiance per channel) for display: multiplied by
/// `exposure`, then the sRGB transfer curve, over the background.
pub fn shade_rgb(channels: [&ValueImage; 3], exposure: f32) -> Result<Picture> {
    let [r, g, b] = channels;
    let (w, h) = (r.width, r.height);
    if [g, b]
        .iter()
        .any(|c| (c.width, c.height) != (w, h) || c.value.len() != r.value.len())
    {
        return Err(Error::InvalidArgument(
            "shade_rgb: the three channel images differ in size".into(),
        ));
    }
    let srgb = |v: f32| {
        let v = v.clamp(0.0, 1.0);
        if v <= 0.003_130_8 {
            12.92 * v
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        }
    };
    let mut rgb = vec![0u8; (w * h * 3) as usize];
    for y in 0..h {
        for x in 0..w {
            let o = (y * w + x) as usize;
            let c = r.coverage[o];
            let value = |img: &ValueImage| {
                let v = img.value[o];
                if c > 0.0 && v.is_finite() { v } else { 0.0 }
            };
            let colour = Vec3::new(
                srgb(value(r) * exposure),
                srgb(value(g) * exposure),
                srgb(value(b) * exposure),
            ) * c
                + background(y, h) * (1.0 - c);
            for k in 0..3 {
                rgb[o * 3 + k] = to_u8(colour[k]);
            }
        }
    }
    Ok(Picture {
        width: w,
        height: h,
        rgb,
    })
}

/// Renders triangles shaded by `value` (0 black .. 1 white, slightly warm, linear) and returns
/// RGB8: [`rasterize`] then [`shade`].
pub fn render(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    value: &[f32],
    frame_points: &[Vec3],
    view: &View,
) -> Vec<u8> {
    shade(&rasterize(positions, triangles, value, frame_points, view)).rgb
}

/// Where the panels of a [`side_by_side`] picture go: a title strip above three panels of
/// the inputs' size, then the colour bar.
#[derive(Clone, Copy, Debug)]
pub struct SideBySideLayout {
    pub panel_width: u32,
    pub panel_height: u32,
}

impl SideBySideLayout {
    /// Height of the title strip above the panels.
    pub const TITLE_HEIGHT: u32 = 28;
    /// Width of the colour bar column.
    pub const BAR_WIDTH: u32 = 112;

    /// Width and height of the whole picture.
    pub fn size(&self) -> (u32, u32) {
        (
            3 * self.panel_width + Self::BAR_WIDTH,
            self.panel_height + Self::TITLE_HEIGHT,
        )
    }

    /// Top-left corner of panel `k` (0 result, 1 truth, 2 error).
    pub fn panel_origin(&self, k: u32) -> (u32, u32) {
        (k * self.panel_width, Self::TITLE_HEIGHT)
    }
}

/// A heat-map colour for `t` in [0, 1] (dark purple, red, orange, pale yellow; monotone in
/// lightness, readable in grey).
pub fn heat(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.0, 0.0, 4.0],
        [87.0, 16.0, 110.0],
        [188.0, 55.0, 84.0],
        [249.0, 142.0, 9.0],
        [252.0, 255.0, 164.0],
    ];
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * (STOPS.len() - 1) as f32;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    [0, 1, 2].map(|k| (a[k] + (b[k] - a[k]) * f + 0.5) as u8)
}

/// A short label for a colour-bar value ("0", "0.25", "1.5E-4").
pub fn label(v: f32) -> String {
    if v == 0.0 {
        return "0".into();
    }
    if v.abs() >= 0.01 && v.abs() < 10_000.0 {
        let s = format!("{v:.3}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        return s.to_string();
    }
    format!("{v:.1E}")
}

/// Result, ground truth and their error side by side at the same camera: `result | truth |
/// error` with the error as a heat map from 0 to `scale` (larger errors saturate) and a
/// colour bar labelled with its values. `error` holds one value per pixel of the inputs,
/// NaN where there is nothing to compare (drawn as background). Every kernel's `--reference`
/// picture is made here.
pub fn side_by_side(
    result: &Picture,
    truth: &Picture,
    error: &[f32],
    scale: f32,
) -> Result<Picture> {
    let (w, h) = (result.width, result.height);
    let n = w as usize * h as usize;
    if (truth.width, truth.height) != (w, h)
        || result.rgb.len() != 3 * n
        || truth.rgb.len() != 3 * n
        || error.len() != n
        || w == 0
        || h == 0
    {
        return Err(Error::InvalidArgument(format!(
            "side-by-side picture: result {}x{} ({} bytes), truth {}x{} ({} bytes) and {} error \
             values do not describe the same image",
            w,
            h,
            result.rgb.len(),
            truth.width,
            truth.height,
            truth.rgb.len(),
            error.len()
        )));
    }
    if !(scale.is_finite() && scale > 0.0) {
        return Err(Error::InvalidArgument(format!(
            "side-by-side picture: error scale {scale} must be finite and > 0"
        )));
    }
    let layout = SideBySideLayout {
        panel_width: w,
        panel_height: h,
    };
    let (tw, th) = layout.size();
    let mut out = Canvas::new(tw, th, [255, 255, 255]);
    let err_rgb: Vec<u8> = (0..n)
        .flat_map(|i| {
            let e = error[i];
            if e.is_nan() {
                let bg = background((i / w as usize) as u32, h);
                [0, 1, 2].map(|k| to_u8(bg[k]))
            } else {
                heat(e / scale)
            }
        })
        .collect();
    let titles = ["RESULT", "TRUTH", "|RESULT - TRUTH|"];
    for (k, (rgb, title)) in [&result.rgb, &truth.rgb, &err_rgb]
        .into_iter()
        .zip(titles)
        .enumerate()
    {
        let (x0, y0) = layout.panel_origin(k as u32);
        out.blit(x0, y0, w, h, rgb);
        out.text(x0 + 8, 7, title, 2, [20, 20, 20]);
        if k > 0 {
            out.fill(x0, y0, 1, h, [255, 255, 255]);
        }
    }
    // The colour bar: top = scale, bottom = 0, with ticks at quarters.
    let bx = 3 * w + 10;
    let (by0, by1) = (SideBySideLayout::TITLE_HEIGHT + 12, th.saturating_sub(24));
    let bar_h = by1.saturating_sub(by0).max(2);
    for y in 0..bar_h {
        let t = 1.0 - y as f32 / (bar_h - 1) as f32;
        out.fill(bx, by0 + y, 18, 1, heat(t));
    }
    out.text(bx - 2, 7, "ERROR", 2, [20, 20, 20]);
    for q in 0..=4u32 {
        let y = by0 + (bar_h - 1) * (4 - q) / 4;
        out.fill(bx + 18, y, 4, 1, [20, 20, 20]);
        let v = scale * q as f32 / 4.0;
        let text = if q == 4 {
            format!("{}+", label(v))
        } else {
            label(v)
        };
        // Large digits where they fit in the bar's column, small ones otherwise.
        let size = if text.len() <= 5 { 2 } else { 1 };
        out.text(
            bx + 29,
            y.saturating_sub(3 * size),
            &text,
            size,
            [20, 20, 20],
        );
    }
    let max = error
        .iter()
        .copied()
        .filter(|e| !e.is_nan())
        .fold(0.0f32, f32::max);
    out.text(
        bx - 2,
        th.saturating_sub(14),
        &format!("MAX {}", label(max)),
        1,
        [20, 20, 20],
    );
    Ok(Picture {
        width: tw,
        height: th,
        rgb: out.rgb,
    })
}

/// The linear twin of a [`side_by_side`] picture: the three panels' float values at the
/// same pixels (alpha 0 in the title strip and the colour bar).
pub fn side_by_side_linear(
    result: &FloatImage,
    truth: &FloatImage,
    error: &FloatImage,
) -> Result<FloatImage> {
    let (w, h) = (result.width, result.height);
    for img in [truth, error] {
        if (img.width, img.height) != (w, h) {
            return Err(Error::InvalidArgument(format!(
                "side-by-side image: panels of {w}x{h} and {}x{}",
                img.width, img.height
            )));
        }
    }
    let layout = SideBySideLayout {
        panel_width: w,
        panel_height: h,
    };
    let (tw, th) = layout.size();
    let mut out = FloatImage::new(tw, th, [0.0; 4]);
    for (k, img) in [result, truth, error].into_iter().enumerate() {
        let (x0, y0) = layout.panel_origin(k as u32);
        for y in 0..h {
            for x in 0..w {
                if let Some(p) = img.get(x, y) {
                    out.set(x0 + x, y0 + y, p);
                }
            }
        }
    }
    Ok(out)
}

/// An RGB8 drawing surface; everything drawn outside is clipped.
struct Canvas {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Canvas {
    fn new(width: u32, height: u32, colour: [u8; 3]) -> Canvas {
        Canvas {
            width,
            height,
            rgb: colour.repeat(width as usize * height as usize),
        }
    }

    fn put(&mut self, x: u32, y: u32, c: [u8; 3]) {
        if x < self.width && y < self.height {
            let o = 3 * (y as usize * self.width as usize + x as usize);
            self.rgb[o..o + 3].copy_from_slice(&c);
        }
    }

    fn fill(&mut self, x0: u32, y0: u32, w: u32, h: u32, c: [u8; 3]) {
        for y in y0..y0.saturating_add(h) {
            for x in x0..x0.saturating_add(w) {
                self.put(x, y, c);
            }
        }
    }

    /// Copies a `w` x `h` RGB8 block to (x0, y0).
    fn blit(&mut self, x0: u32, y0: u32, w: u32, h: u32, rgb: &[u8]) {
        for y in 0..h {
            for x in 0..w {
                let o = 3 * (y as usize * w as usize + x as usize);
                if let Some(p) = rgb.get(o..o + 3) {
                    self.put(x0 + x, y0 + y, [p[0], p[1], p[2]]);
                }
            }
        }
    }

    /// Draws `text` with the built-in 5x7 font, each font pixel `size` x `size`.
    fn text(&mut self, x0: u32, y0: u32, text: &str, size: u32, c: [u8; 3]) {
        for (i, ch) in text.chars().enumerate() {
            let rows = glyph(ch);
            let gx = x0 + i as u32 * 6 * size;
            for (r, bits) in rows.iter().enumerate() {
                for col in 0..5u32 {
                    if bits >> (4 - col) & 1 == 1 {
                        self.fill(gx + col * size, y0 + r as u32 * size, size, size, c);
                    }
                }
            }
        }
    }
}

/// The 5x7 bitmap of `c` (rows top to bottom, bit 4 = leftmost column); lower case is drawn
/// as upper case, unknown characters as blanks.
fn glyph(c: char) -> [u8; 7] {
    match c.to_ascii_uppercase() {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '+' => [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00],
        '|' => [0x04; 7],
        ':' => [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00],
        '=' => [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00],
        '(' => [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02],
        ')' => [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08],
        '/' => [0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        'A' => [0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11],
        'B' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'C' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'D' => [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'F' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'H' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'J' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'K' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'P' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'Q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'U' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'W' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'Y' => [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04],
        'Z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        _ => [0; 7],
    }
}

/// Writes an RGB8 image as PNG, atomically.
#[cfg(feature = "png")]
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    let img = image::RgbImage::from_raw(width, height, rgb.to_vec()).ok_or_else(|| {
        Error::input(
            path,
            format!("{} bytes are not a {width}x{height} RGB image", rgb.len()),
        )
    })?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| Error::input(path, format!("PNG encoding failed: {e}")))?;
    crate::io::write_atomic(path, &png)
}

/// Writes RGB8 frames as an animated PNG (APNG; every frame `delay_ms` long, looping),
/// atomically.
#[cfg(feature = "png")]
pub fn write_apng(
    path: &Path,
    width: u32,
    height: u32,
    frames: &[Vec<u8>],
    delay_ms: u16,
) -> Result<()> {
    let fail = |e: png::EncodingError| Error::input(path, format!("APNG encoding failed: {e}"));
    let n = width as usize * height as usize * 3;
    if frames.is_empty() || frames.iter().any(|f| f.len() != n) {
        return Err(Error::input(
            path,
            format!("APNG needs at least one frame of {width}x{height} RGB bytes"),
        ));
    }
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_animated(frames.len() as u32, 0).map_err(fail)?;
        enc.set_frame_delay(delay_ms, 1000).map_err(fail)?;
        let mut w = enc.write_header().map_err(fail)?;
        for f in frames {
            w.write_image_data(f).map_err(fail)?;
        }
        w.finish().map_err(fail)?;
    }
    crate::io::write_atomic(path, &bytes)
}

/// Writes an animated PNG: compiled out (feature `png`), always an error naming it.
#[cfg(not(feature = "png"))]
pub fn write_apng(
    path: &Path,
    _width: u32,
    _height: u32,
    _frames: &[Vec<u8>],
    _delay_ms: u16,
) -> Result<()> {
    Err(Error::feature(format!("writing {}", path.display()), "png"))
}

/// Writes an RGB8 image as PNG: compiled out (feature `png`), always an error naming it.
#[cfg(not(feature = "png"))]
pub fn write_png(path: &Path, _width: u32, _height: u32, _rgb: &[u8]) -> Result<()> {
    Err(Error::feature(
        format!("writing the PNG {}", path.display()),
        "png",
    ))
}
