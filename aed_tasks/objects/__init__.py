"""Builders of the benchmark's objects, from primitives, generated meshes and textures.

Concave objects are compounds of convex pieces, so that contact (not attachment) holds
whatever they contain or carry.
"""
