"""Offscreen pictures of a finished run, from its exported files only (used by `pdmpm render`).

The run is read from ``OUT/run.h5`` or, when a scene turned HDF5 off, from the ParaView series
(``OUT/vtk/particles.pvd``) and ``OUT/meshes/*.ply``; the scene's inputs are never needed (`source`). Each body is
drawn the way it reads best (`scene`): shells as their smooth surface, Voronoi bodies as solid cell polyhedra (so
fragments show as pieces), viscoelastic fluids as a surface reconstructed from the particles, everything
else as spheres. All frames share one colour range (`fields`) and one Plotter (a fresh one per frame costs
seconds). `run.render_run` ties them together with the options (`options`) and the video (`video`); `sheet` tiles
stills. Library code: progress goes to a callback, nothing is printed.
"""
