"""Building blocks of the synthetic stereo 360° recordings; the public entry point is
`pipeline.simulate`.

Modules
-------
config      settings (`SimulationConfig`) and scenario presets
rig         camera pose, delay and recording windows drawn from the seed
fireflies   flights and flash schedules (synthetic)
real3d      flights and flash timing replayed from real 3D data
lights      lamps, moon, car headlights and flashlights as moving light sources
foliage     wind-shaken leaves silhouetted against the sky
background  static sky / treeline / ground images per camera
render      anti-aliased spots and discs splatted into small windows
encode      chapter files through PyAV
tables      ground-truth tables and their CSV files
"""
