"""The capture light: estimate it from the views, and read each point's material against it.

A point seen by several views under a known environment pins its material: for fixed roughness
r and metallic m the split-sum shader (``eval.relight``) is affine in the linear albedo, so a
grid over (r, m) with the least-squares albedo in each cell gives the evidence for every
material (``readout``). The same residual, minimised over candidate environments, their
rotation about the up axis and a gain, tells the light (``estimate``).

Modules: ``observations`` (a point's views as one record), ``shading`` (the shader's affine
terms), ``readout`` (grid fit, neighbourhood pooling, read-outs), ``estimate`` (which light).
"""
