"""Test and benchmark fixtures: data sets whose answer is known, in the real on-disk layout.

- `constructed`: frames ray-cast through the rig's camera models (a ground plane and boxes), EXR
  passes and all, without Blender (label tests, the fusion bench)
- `blender_constructed`: the same geometry built and rendered by real Blender (label fidelity proof)
- `toy_data`: a small fused data set (images + labels + index.json) for model tests and benchmarks

Nothing in the production packages imports this one.
"""
