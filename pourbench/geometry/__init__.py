"""Pure numpy geometry below every other package: container shapes and their SDFs
(:mod:`pourbench.geometry.shapes`). Importing it loads neither MuJoCo nor Warp."""
