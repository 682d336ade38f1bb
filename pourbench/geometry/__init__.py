"""Pure numpy geometry below every other package: container shapes and their SDFs
(:mod:`~pourbench.geometry.shapes`), the lattices that fill their cavities
(:mod:`~pourbench.geometry.fill`) and rotations (:mod:`~pourbench.geometry.rotation`).
Importing it loads neither MuJoCo nor Warp."""
