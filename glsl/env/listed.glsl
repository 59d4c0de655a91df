// Which vertex invocation i of an env pass shades. Without ENV_LISTED: vertex i of
// pc.vertex_count. With ENV_LISTED (passes dispatched indirectly over this frame's vertex
// list, written by pass `vertex list`, glsl/raster/vertex_list.comp): the list's entry i of
// head[3]. The list's binding is 10 in every pass that includes this.
#ifndef VKSHADE_ENV_LISTED_GLSL
#define VKSHADE_ENV_LISTED_GLSL
#ifdef ENV_LISTED
layout(std430, set = 0, binding = 10) readonly buffer Listed { uint head[4]; uint v[]; } listed;
bool listed_vertex(uint i, out uint vi) {
    vi = 0u;
    if (i >= listed.head[3]) return false;
    vi = listed.v[i];
    return vi < pc.vertex_count;
}
#else
bool listed_vertex(uint i, out uint vi) {
    vi = i;
    return i < pc.vertex_count;
}
#endif
#endif
