//! A small CPU rasteriser for pictures of meshes shaded by a per-vertex value (z-buffer,
//! orthographic camera, Gouraud interpolation, 2x2 supersampling). It makes the PNGs the
//! CLI writes; it is not a kernel.

use crate::error::{Error, Result};
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

/// Renders triangles shaded by `value` (0 black .. 1 white, slightly warm, linear) and returns
/// RGB8.
/// The camera frames `frame_points` (e.g. the bounds of a whole animation).
pub fn render(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    value: &[f32],
    frame_points: &[Vec3],
    view: &View,
) -> Vec<u8> {
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
    let mut shade = vec![-1.0f32; (w * h) as usize];
    for t in triangles {
        let [a, b, c] = t.map(|i| screen[i as usize]);
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
                    shade[i] = w0 * va + w1 * vb + w2 * vc;
                }
            }
        }
    }
    let mut out = vec![0u8; (view.width * view.height * 3) as usize];
    for y in 0..view.height {
        for x in 0..view.width {
            let mut rgb = Vec3::ZERO;
            for sy in 0..ss {
                for sx in 0..ss {
                    let i = ((y * ss + sy) * w + x * ss + sx) as usize;
                    rgb += if shade[i] >= 0.0 {
                        Vec3::new(1.0, 0.96, 0.9) * shade[i].clamp(0.0, 1.0)
                    } else {
                        let g = 0.16 + 0.08 * (y as f32 / view.height as f32);
                        Vec3::new(g * 0.8, g * 0.9, g * 1.1)
                    };
                }
            }
            rgb /= (ss * ss) as f32;
            let o = ((y * view.width + x) * 3) as usize;
            for k in 0..3 {
                // Shown linearly, as ambient-occlusion maps conventionally are (a display
                // gamma would wash out everything above 0.8).
                out[o + k] = (rgb[k].clamp(0.0, 1.0) * 255.0 + 0.5) as u8;
            }
        }
    }
    out
}

/// Writes an RGB8 image as PNG, atomically.
pub fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    let img = image::RgbImage::from_raw(width, height, rgb.to_vec())
        .ok_or_else(|| Error::InvalidArgument("image buffer size mismatch".into()))?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| Error::InvalidArgument(format!("PNG encoding failed: {e}")))?;
    crate::shaders::write_atomic(path, &png)
}
