"""What every fit solves (docs/design.md, section 6): targets and constraints, the unknowns
(`Layout`), the point kernel (`tree_points`: points on the body for a free vector, with
closed-form derivatives), the weighted least-squares problem (`Problem`) and the plans that
make the whole tree's and the limb chains' programs serve every effector set. The reach
(`ik`), the markers (`mocap`) and the sphere clouds (`clouds`) build on it."""
