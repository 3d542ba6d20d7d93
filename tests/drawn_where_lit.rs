//! Drawn = lit (issue 35, item 2): the renderer draws each instance where the lighting stages
//! placed it. With a `bittree` section the renderer decodes the instances from it; before its
//! per-instance residuals the fixture's were drawn at their leaf cells' centres, up to half a
//! cell (metres) from the positions their light maps and env maps were baked at. The oracle is
//! the `instances` section (the list every lighting stage reads), paired by model and order.

mod common;

#[test]
fn every_instance_is_drawn_within_a_centimetre_of_where_it_was_lit() {
    let dir = tempfile::tempdir().unwrap();
    let path = common::preview_fixture_pack(dir.path());
    let pack = bake::pack::Pack::open(&path).unwrap();
    assert!(
        pack.of_kind(bake::bittree::section::KIND).next().is_some(),
        "the preview pipeline writes a bittree section"
    );
    let (_, list) =
        bake::ingest::instances_section::from_section(&pack.view_named("instances").unwrap())
            .unwrap();
    let scene = bake::render::scene::load_scene(&pack).unwrap();
    assert_eq!(
        scene.instance_source,
        bake::render::scene::InstanceSource::Bittree
    );
    // The renderer keeps each model's instances in list order.
    let mut drawn = 0;
    let mut worst = 0.0f32;
    for m in &scene.models {
        let want: Vec<_> = list
            .items
            .iter()
            .filter(|i| list.models[i.model as usize] == m.name)
            .collect();
        assert_eq!(want.len(), m.instances.len(), "model {}", m.name);
        for (w, d) in want.iter().zip(&m.instances) {
            for a in 0..3 {
                worst = worst.max((w.position[a] - d.position[a]).abs());
            }
            drawn += 1;
        }
    }
    assert_eq!(drawn, list.items.len());
    assert!(
        worst <= 0.01,
        "an instance drawn {worst} m from where it was lit"
    );
}
