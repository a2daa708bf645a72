"""The body's tree and the roles of its parts (`Body.path_to_top`, `.trunk`, `.feet`,
`.thighs`, `.below`), as the solver reads them, on the default body and on bodies of other
names."""

from bodies import mini_doc, write

import diffbody as db


def _names(body, segments) -> set[str]:
    return {body.segment_names[s] for s in segments}


def test_the_default_body_s_roles(male50):
    assert _names(male50, male50.feet) == {"left_foot", "right_foot"}
    assert _names(male50, male50.thighs) == {"left_thigh", "right_thigh"}
    below = {"left_shank", "right_shank", "left_foot", "right_foot"}
    assert _names(male50, male50.below(male50.thighs)) == below
    # the vertebrae with the neck and what lies above them: the pelvis, not its halves
    assert _names(male50, male50.trunk) == {"whole_body", "pelvis", *male50.spine.segment_names}


def test_a_path_runs_from_the_segment_to_the_whole_body(male50):
    for s in range(male50.n_segments):
        path = male50.path_to_top(s)
        assert path[0] == s and path[-1] == 0
        assert all(male50.parent[a] == b for a, b in zip(path, path[1:]))
    hand = male50.path_to_top(male50.segment_index("left_hand"))
    arm = ["left_hand", "left_forearm", "left_upper_arm", "left_clavicle", "T1"]
    assert [male50.segment_names[s] for s in hand[:5]] == arm


def test_roles_follow_the_names(tmp_path):
    """A body whose legs end in other names stands on what it names `*_foot`; one without
    such names has no feet and no spine database, so its trunk is the whole body alone."""
    mini = db.load_body(write(mini_doc(), tmp_path / "mini.json"))
    assert mini.feet == () and mini.trunk == {0}
    doc = mini_doc()
    for s in doc["segments"]:
        if s["name"] == "left_thigh":
            s["name"] = "hind_foot"
    hind = db.load_body(write(doc, tmp_path / "hind.json"))
    assert _names(hind, hind.feet) == {"hind_foot"} and hind.thighs == ()


def test_asking_a_body_its_roles_leaves_its_pytree_as_it_was(male50):
    """Regression: the roles as cached properties went into the body's pytree structure, so
    a body asked for its trunk hashed (and compiled) as another body: a resumed batch was
    refused, "the body changed"."""
    import jax

    from diffbody.runs._streaming import tree_hash

    body = db.load_body()
    structure, digest = jax.tree.structure(body), tree_hash(body)
    body.trunk, body.feet, body.thighs, body.below(body.thighs), body.path_to_top(3)
    assert jax.tree.structure(body) == structure and tree_hash(body) == digest
