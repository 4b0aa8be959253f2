"""`--config=auto`: a config decided from the training views and the user's flags.

  auto.py            auto_config, the loop over the rules, and the step rule (by_steps)
  rule.py            the Rule record and the Context every rule reads
  rules/             one module per rule, each defining RULE; rules/__init__.py orders them
  characterise.py    the measurements on the training views (pure numpy)
  resolution.py      the photos' size, decided before they are read
  warm_up.py, transient_share.py   the transients' statistic after a short warm-up
"""
