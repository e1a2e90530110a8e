//! GLB writing (stub).
