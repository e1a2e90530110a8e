//! ARKit blendshapes to visemes (stub).
