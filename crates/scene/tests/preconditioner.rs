//! `simulation.preconditioner`: its values, its default and the located error of a bad one.

use std::path::Path;

use softbody_scene::{Preconditioner, Scene};

fn scene(line: &str) -> String {
    format!(
        "[simulation]\ndt = 0.01\nduration = 1.0\n{line}\n[[body]]\nkind = \"cuboid\"\n\
         size = [1.0, 1.0, 1.0]\nresolution = [3, 3, 3]\nmass = 1.0\nstructural = {{ stiffness = 100.0 }}\n"
    )
}

#[test]
fn the_preconditioner_key_takes_its_two_values_and_defaults_to_multigrid() {
    let origin = Path::new("scene.toml");
    let parse = |line: &str| Scene::from_toml(&scene(line), origin).unwrap();
    assert_eq!(
        parse("").simulation.preconditioner,
        Preconditioner::Multigrid
    );
    assert_eq!(
        parse("preconditioner = \"multigrid\"")
            .simulation
            .preconditioner,
        Preconditioner::Multigrid
    );
    assert_eq!(
        parse("preconditioner = \"block-jacobi\"")
            .simulation
            .preconditioner,
        Preconditioner::BlockJacobi
    );
    let e = Scene::from_toml(&scene("preconditioner = \"amg\""), origin).unwrap_err();
    let d = e.diagnostic().expect("a located error");
    assert_eq!(
        (d.line, d.key.to_string()),
        (4, "simulation.preconditioner".to_owned())
    );
    assert!(
        d.message
            .starts_with("unknown variant `amg`, expected `multigrid` or `block-jacobi`"),
        "{}",
        d.message
    );
    assert_eq!("block-jacobi".parse(), Ok(Preconditioner::BlockJacobi));
    assert!("amg".parse::<Preconditioner>().is_err());
}
