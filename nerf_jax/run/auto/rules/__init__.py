"""auto's rules, in the order they run and print their lines (auto.auto_config). A new rule is
one module here defining RULE (rule.Rule), its place in RULES, a test and its row in
docs/auto.md's table (docs/extending.md, "Adding an auto rule")."""

from nerf_jax.run.auto.rules import (appearance, background, backend, cones, contraction, depth,
                                     focus, forward, large_objects, photo_size, pose_refinement,
                                     step_rule, subject_box, too_few, transients, unbounded,
                                     view_dependence, your_flags)

RULES = (photo_size.RULE, too_few.RULE, large_objects.RULE, background.RULE, forward.RULE,
         unbounded.RULE, appearance.RULE, view_dependence.RULE, cones.RULE, contraction.RULE,
         focus.RULE, subject_box.RULE, transients.RULE, depth.RULE, pose_refinement.RULE,
         step_rule.RULE, backend.RULE, your_flags.RULE)
