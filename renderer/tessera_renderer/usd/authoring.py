"""Which layer gave an attribute its value: asset paths (textures, IES profiles, MaterialX
documents) resolve against that layer's folder. Its own module because materials, MaterialX,
lights and light shaping all read it, and none of them should import another for it."""


def authoring_layer(attr):
    """The layer whose opinion gives an attribute its value (for anchoring asset paths)."""
    for spec in attr.GetPropertyStack():
        if spec.HasDefaultValue() or spec.layer.GetNumTimeSamplesForPath(spec.path):
            return spec.layer
    return None
