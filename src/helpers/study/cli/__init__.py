"""The study's command-line tools, each run as ``python -m helpers.study.cli.<tool>``: ``runner`` (notebooks with a
preset via papermill), ``zoo`` (train, publish, verify the committed models), ``byo`` (a rotation from your mesh and
photo), ``cache`` (list, verify, prune the cache), ``readme`` (the README's headline from claims.json) and
``ddp_train`` (one split's model on several processes). Nothing below this package imports it."""
