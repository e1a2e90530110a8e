//! glTF loading (stub).
