//! Synthetic BTFs: the cloth model of [`super::cloth`] tabulated at the 81 x 81 sampled
//! light and view directions, sRGB coding, and UBO2003-style directories on disk.

use super::cloth::SynthConfig;
use super::dirs::{self, Angles};
use crate::error::{Error, Result};
use rayon::prelude::*;

/// A BTF in memory: for each (view, light) pair of the 81 x 81 sampled directions an image
/// of `size` texels, linear RGB.
#[derive(Clone, Debug)]
pub struct Btf {
    /// Width and height in texels.
    pub size: [u32; 2],
    /// Slice-major (slice = view * 81 + light), then row-major texels.
    pub texels: Vec<[f32; 3]>,
}

impl Btf {
    /// Texels per image.
    pub fn image_len(&self) -> usize {
        self.size[0] as usize * self.size[1] as usize
    }

    /// The image of slice `view * 81 + light`.
    pub fn image(&self, light: usize, view: usize) -> &[[f32; 3]] {
        let n = self.image_len();
        let s = view * dirs::COUNT + light;
        &self.texels[s * n..(s + 1) * n]
    }

    /// The UBO2003-style file name of a (light, view) pair.
    pub fn file_name(light: Angles, view: Angles, ext: &str) -> String {
        format!(
            "btf_tl{:03}_pl{:03}_tv{:03}_pv{:03}.{ext}",
            light.theta, light.phi, view.theta, view.phi
        )
    }
}

/// Synthesises the 81 x 81 images of `cfg` (rayon over the images).
pub fn synthesize(cfg: &SynthConfig) -> Result<Btf> {
    cfg.check()?;
    let d = dirs::directions();
    let images: Vec<Vec<[f32; 3]>> = (0..dirs::COUNT * dirs::COUNT)
        .into_par_iter()
        .map(|s| cfg.image(d[s % dirs::COUNT].vector(), d[s / dirs::COUNT].vector()))
        .collect();
    Ok(Btf {
        size: cfg.size,
        texels: images.concat(),
    })
}

/// sRGB encoding of a linear value (clamped to [0, 1]) to 8 bits.
pub fn srgb_encode(x: f32) -> u8 {
    let x = x.clamp(0.0, 1.0) as f64;
    let s = if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round() as u8
}

/// sRGB decoding of an 8-bit value to linear.
pub fn srgb_decode(b: u8) -> f64 {
    let s = b as f64 / 255.0;
    if s <= 0.040_45 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

/// Image format of a written BTF directory.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum FileFormat {
    /// 8-bit sRGB-encoded PNG (values above 1 clip).
    Png,
    /// Linear 32-bit float EXR.
    Exr,
}

/// Writes `btf` as a UBO2003-style directory `dir` (one image per (light, view) pair, the
/// angles in the names) plus `btf.json` describing it, for the command `command` (named in
/// the directory's marker). The directory must be new, empty, or one `command` wrote before
/// (see [`crate::io::outdir`]): an existing file or a directory of other files is refused
/// and left untouched. The images go to a temporary folder beside `dir`, swapped in when
/// all are written: readers never see half a data set.
pub fn write_dir(
    btf: &Btf,
    dir: &std::path::Path,
    format: FileFormat,
    about: &impl serde::Serialize,
    command: &str,
) -> Result<()> {
    if let Some(i) = btf
        .texels
        .iter()
        .position(|t| t.iter().any(|c| !c.is_finite()))
    {
        let n = btf.image_len().max(1);
        let d = dirs::directions();
        let (s, texel) = (i / n, i % n);
        return Err(Error::input(
            dir,
            format!(
                "not written: texel {texel} of image {} is non-finite ({:?})",
                Btf::file_name(d[s % dirs::COUNT], d[s / dirs::COUNT], "*"),
                btf.texels[i]
            ),
        ));
    }
    crate::io::outdir::replace(dir, command, |tmp| {
        let d = dirs::directions();
        let [w, h] = btf.size;
        (0..dirs::COUNT * dirs::COUNT)
            .into_par_iter()
            .try_for_each(|s| -> Result<()> {
                let (l, v) = (s % dirs::COUNT, s / dirs::COUNT);
                let img = btf.image(l, v);
                match format {
                    FileFormat::Png => {
                        let path = tmp.join(Btf::file_name(d[l], d[v], "png"));
                        let rgb: Vec<u8> = img.iter().flat_map(|p| p.map(srgb_encode)).collect();
                        write_png_plain(&path, w, h, &rgb)
                    }
                    FileFormat::Exr => {
                        #[cfg(feature = "exr")]
                        {
                            let path = tmp.join(Btf::file_name(d[l], d[v], "exr"));
                            let fi = crate::io::FloatImage {
                                width: w,
                                height: h,
                                pixels: img.iter().map(|p| [p[0], p[1], p[2], 1.0]).collect(),
                            };
                            crate::io::exr::write(&path, &fi, crate::io::exr::Channels::Rgb)
                        }
                        #[cfg(not(feature = "exr"))]
                        Err(Error::feature("writing EXR BTF images", "exr"))
                    }
                }
            })?;
        crate::io::write_json(&tmp.join("btf.json"), about)
    })
}

#[cfg(feature = "png")]
fn write_png_plain(path: &std::path::Path, w: u32, h: u32, rgb: &[u8]) -> Result<()> {
    image::save_buffer(path, rgb, w, h, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::input(path, format!("PNG encoding failed: {e}")))
}

#[cfg(not(feature = "png"))]
fn write_png_plain(path: &std::path::Path, _w: u32, _h: u32, _rgb: &[u8]) -> Result<()> {
    Err(Error::feature(
        format!("writing the PNG {}", path.display()),
        "png",
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trip() {
        for b in 0..=255u8 {
            assert_eq!(srgb_encode(srgb_decode(b) as f32), b);
        }
    }
}
