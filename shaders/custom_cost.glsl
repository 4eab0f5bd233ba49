// Placeholder for a user's cost (gltrack.render.engine.CustomCost replaces this file through an
// include alias). Contract: float custom_cost(ivec2 pixel, ivec2 local), summed per tile into
// channel "custom". See examples/05_custom_cost_shader.py.
float custom_cost(ivec2 pixel, ivec2 local) {
    return 0.0;
}
