#version 450
#include <common/util.glsl>
// Clustered-PCA projection: for every row r of every cluster (its mean, then its principal
// axes, zero-padded to a whole number of groups of four), p_r = sum_k row_rk c_k (RGB), c_k
// the lighting's coefficients in the transfer basis. Rows are stored in groups of four basis
// functions, group-major: rows4[g * rows + r], so neighbouring invocations read neighbouring
// vec4s, from an image (one vector gather on lavapipe, where a storage-buffer load is a loop
// over the lanes); the coefficients are the same for every invocation (a uniform buffer).
// p_r goes to texel r (SRBF_ROW a row) of the image `srbf shade` reads.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint rows;
    uint groups;   // ceil(basis / 4)
} pc;

layout(set = 0, binding = 0, rgba32f) uniform readonly image2D rows;  // SRBF_ROW texels wide
layout(constant_id = 0) const uint SRBF_ROW = 4096u; // kernels::table_row
const uint MAX_BASIS = 1024u;
layout(std140, set = 0, binding = 1) uniform Coeffs { vec4 v[MAX_BASIS]; } coeffs; // zero-padded
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D projected;

void main() {
    uint r = gl_GlobalInvocationID.x;
    if (r >= pc.rows) return;
    vec3 sum = vec3(0.0);
    uint index = r;
    for (uint g = 0u; g < pc.groups; g++) {
        vec4 t = imageLoad(rows, table_texel(index, SRBF_ROW));
        uint k = 4u * g;
        sum += t.x * coeffs.v[k].rgb + t.y * coeffs.v[k + 1u].rgb + t.z * coeffs.v[k + 2u].rgb
            + t.w * coeffs.v[k + 3u].rgb;
        index += pc.rows;
    }
    imageStore(projected, table_texel(r, SRBF_ROW), vec4(sum, 0.0));
}
