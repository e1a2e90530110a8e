//! The default network compiled into the client (paper III.C.3): the model file is part of the
//! binary, so nothing is read at run time, and it is parsed by the one model reader.

use super::network::Model;

const SHIPPED: &str = include_str!("../../assets/models/default.lipmodel");

/// The shipped default network, parsed once. Its viseme names are `shipped().viseme_names()`.
pub fn shipped() -> &'static Model {
    static MODEL: std::sync::OnceLock<Model> = std::sync::OnceLock::new();
    // The file is compiled in and a unit test loads it: only a broken build fails here.
    MODEL.get_or_init(|| Model::from_text(SHIPPED).expect("the shipped model file parses"))
}

/// An owned copy of the shipped network, for callers that adjust it.
pub fn default_model() -> Model {
    shipped().clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shipped_model_loads_within_budget() {
        let model = Model::from_text(SHIPPED).unwrap();
        assert_eq!(default_model(), model);
        assert!(model.multiply_adds() <= super::super::network::MULTIPLY_ADD_BUDGET);
    }
}
