"""One generative program per Savarese category, grouped by family.

Each builder has the signature ``builder(rng, tex_seed) -> list[Part]``: ``rng`` (a NumPy generator
seeded from the instance seed) draws the shape and material choices, ``tex_seed`` seeds the textures.
Builders work in convenient units with the front along +x and the ground at z = 0;
`scrppl.datasets.synthetic.shapes.build_instance` normalises the result to the canonical frame.
"""
