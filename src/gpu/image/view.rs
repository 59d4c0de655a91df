//! Image views: described by [`ViewDesc`], created on first use and cached per image.

use super::format::{format_features_for, texel_size};
use super::{Image, ImageDesc, ImageDim, ImageInner, Subresources};
use crate::error::{Error, Result, VkResultExt};
use crate::gpu::validation::lock;
use ash::vk;

/// A view of an image: type and format (the image's when `None`) and subresources (all of
/// them when `None`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ViewDesc {
    /// The view type; `None` picks one from the image and the subresources.
    pub view_type: Option<vk::ImageViewType>,
    /// The view's format; `None` is the image's (another needs `mutable_format`).
    pub format: Option<vk::Format>,
    /// The mips and layers seen; `None` is all of them.
    pub subresources: Option<Subresources>,
}

impl ViewDesc {
    /// Views the image as `format` (same texel size; the image needs `mutable_format`).
    pub fn format(mut self, format: vk::Format) -> Self {
        self.format = Some(format);
        self
    }

    /// Sets the view type (checked against the image and the layer count).
    pub fn view_type(mut self, t: vk::ImageViewType) -> Self {
        self.view_type = Some(t);
        self
    }

    /// Restricts the view to `s`.
    pub fn subresources(mut self, s: Subresources) -> Self {
        self.subresources = Some(s);
        self
    }
}

impl Image {
    /// The view over every subresource with the image's own format.
    pub fn view(&self) -> Result<vk::ImageView> {
        self.inner
            .view(&ViewDesc::default(), vk::ImageUsageFlags::empty())
    }

    /// A view (created on first use, then cached).
    pub fn view_with(&self, desc: &ViewDesc) -> Result<vk::ImageView> {
        self.inner.view(desc, vk::ImageUsageFlags::empty())
    }
}

impl ImageInner {
    /// The subresources a view covers.
    pub(crate) fn view_range(&self, desc: &ViewDesc) -> Subresources {
        desc.subresources.unwrap_or_else(|| self.desc.all())
    }

    /// Creates or finds the view. `needs` are the usages the caller binds it for (checked
    /// against the view format's features).
    pub(crate) fn view(
        &self,
        desc: &ViewDesc,
        needs: vk::ImageUsageFlags,
    ) -> Result<vk::ImageView> {
        let range = self.view_range(desc);
        range.check(&self.name, &self.desc)?;
        let format = desc.format.unwrap_or(self.desc.format);
        if format != self.desc.format && !self.desc.mutable_format {
            return Err(Error::InvalidArgument(format!(
                "a {format:?} view of image '{}' ({:?}) needs the image created with \
                 mutable_format()",
                self.name, self.desc.format
            )));
        }
        if format != self.desc.format
            && (texel_size(format).is_none() || texel_size(format) != texel_size(self.desc.format))
        {
            return Err(Error::InvalidArgument(format!(
                "view format {format:?} is not size-compatible with image '{}' ({:?})",
                self.name, self.desc.format
            )));
        }
        if !needs.is_empty() {
            self.shared.require_format(
                format,
                format_features_for(needs),
                &format!("a view of image '{}' used as {needs:?}", self.name),
            )?;
        }
        let view_type = desc.view_type.unwrap_or_else(|| {
            let d = ImageDesc {
                layers: range.layer_count,
                ..self.desc
            };
            if d.dim == ImageDim::Cube && !range.layer_count.is_multiple_of(6) {
                if range.layer_count == 1 {
                    vk::ImageViewType::TYPE_2D
                } else {
                    vk::ImageViewType::TYPE_2D_ARRAY
                }
            } else {
                d.default_view_type()
            }
        });
        check_view_type(&self.name, &self.desc, view_type, &range)?;
        let key = ViewDesc {
            view_type: Some(view_type),
            format: Some(format),
            subresources: Some(range),
        };
        let mut views = lock(&self.views);
        if let Some(&v) = views.get(&key) {
            return Ok(v);
        }
        // A view whose format cannot be stored to must not inherit the image's STORAGE usage.
        let mut usage = self.desc.usage;
        if !self
            .shared
            .format_features(format)
            .contains(vk::FormatFeatureFlags::STORAGE_IMAGE)
        {
            usage &= !vk::ImageUsageFlags::STORAGE;
        }
        let mut usage_info = vk::ImageViewUsageCreateInfo::default().usage(usage);
        let info = vk::ImageViewCreateInfo::default()
            .image(self.raw)
            .view_type(view_type)
            .format(format)
            .subresource_range(range.vk())
            .push_next(&mut usage_info);
        // SAFETY: the image is alive and bound; type, format and range were checked.
        let view =
            unsafe { self.shared.device.create_image_view(&info, None) }.vk("vkCreateImageView")?;
        self.shared.set_name(
            view,
            &format!(
                "{} view {format:?} mips {}+{} layers {}+{}",
                self.name, range.base_mip, range.mip_count, range.base_layer, range.layer_count
            ),
        );
        views.insert(key, view);
        Ok(view)
    }
}

/// Fails unless a `view_type` view of `range` is allowed for an image of `desc`.
fn check_view_type(
    name: &str,
    desc: &ImageDesc,
    view_type: vk::ImageViewType,
    range: &Subresources,
) -> Result<()> {
    use vk::ImageViewType as T;
    let n = range.layer_count;
    let ok = match (desc.dim, view_type) {
        (ImageDim::D3, T::TYPE_3D) => true,
        (ImageDim::D3, _) | (_, T::TYPE_3D) => false,
        (_, T::TYPE_2D) => n == 1,
        (_, T::TYPE_2D_ARRAY) => true,
        (ImageDim::Cube, T::CUBE) => n == 6,
        (ImageDim::Cube, T::CUBE_ARRAY) => n.is_multiple_of(6),
        _ => false,
    };
    if !ok {
        return Err(Error::InvalidArgument(format!(
            "a {view_type:?} view of {n} layer(s) of image '{name}' ({:?}, {} layers) is not \
             possible",
            desc.dim, desc.layers
        )));
    }
    Ok(())
}
