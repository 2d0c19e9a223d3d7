"""The assertion language: from the text a user writes to the automaton that checks it.

One stage a module, each over the ones below it (the import contract in
pyproject.toml says so):

- ``assertion``: the whole front end, :func:`parse_assertion`, and its warnings;
- ``timed``: how each time-bounded operator is read (obligations, late, at the first
  instant); ``synthesis``: the formula to a monitor automaton (a table over letters);
- ``formula``: the syntax tree lowered to Spot's formula over placeholders (past
  operators as derived placeholders, time-bounded ones cut out); ``parser``: tokens
  to the typed syntax tree (Spot's grammar and edgerv's additions);
- ``bounded``: time-bounded operators read by past ones, a delay late (Maler,
  Nickovic and Pnueli); ``comparisons``: atoms read from tokens, typed;
  ``brackets``: time bounds, step ranges and SERE repetitions;
- the leaves: ``tree`` (the syntax tree), ``lexer`` (tokens, durations, size
  limits), ``atoms`` (what an atom is, the letters that can occur), ``past`` (past
  operators step by step), ``spot_worker`` (Spot in a child process with a budget).

Nothing here knows ROS, Kubernetes or the handler; the core's monitor runs what it
makes.
"""
