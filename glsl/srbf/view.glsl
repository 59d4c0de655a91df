// The view lookup of the glossy passes (glossy.comp, cta_shade.comp; src/kernels/srbf/glossy.rs
// `ViewBasis::weights` is the CPU twin): the direction toward the camera in the vertex's
// tangent frame (Duff et al. 2017, built from the normal alone), clamped onto the horizon
// below it, mapped to the parabolic disk p = (x, y) / (1 + z) and its four bilinear taps in
// an N x N grid (the view nodes, or the BRDF factor table's nodes).
void view_taps(vec3 x, vec3 n, vec3 camera, uint grid, out uint idx[4], out float w[4]) {
    float sgn = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (sgn + n.z);
    float b = n.x * n.y * a;
    vec3 t = vec3(1.0 + sgn * n.x * n.x * a, sgn * b, -sgn * n.x);
    vec3 bt = vec3(b, sgn + n.y * n.y * a, -n.y);
    vec3 o = camera - x;
    if (dot(o, o) == 0.0) o = n;
    vec3 l = vec3(dot(t, o), dot(bt, o), max(dot(n, o), 0.0));
    if (l.x == 0.0 && l.y == 0.0 && l.z == 0.0) l = vec3(1.0, 0.0, 0.0);
    l = normalize(l);
    float s = float(grid - 1u);
    vec2 p = l.xy / (1.0 + l.z);
    vec2 u = clamp((p + 1.0) * 0.5 * s, vec2(0.0), vec2(s));
    uvec2 c = min(uvec2(floor(u)), uvec2(grid - 2u));
    vec2 f = u - vec2(c);
    uint j00 = c.y * grid + c.x;
    idx = uint[4](j00, j00 + 1u, j00 + grid, j00 + grid + 1u);
    w = float[4]((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
}
