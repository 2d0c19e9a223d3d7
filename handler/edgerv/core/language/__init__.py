"""The assertion language: from the text a user writes to the automaton that checks it.

One stage a module, each over the one before:

- ``assertion``: the front end (atoms to placeholders, the formula to Spot) and
  the choice of reading for each time-bounded operator;
- ``bounded``: time-bounded future operators read by past ones, a delay late
  (Maler, Nickovic and Pnueli);
- ``past``: past operators, timed or not, as derived placeholders;
- ``synthesis``: the formula to a monitor automaton (a table over letters);
- ``spot_worker``: Spot in a child process with a time and memory budget.

Nothing here knows ROS, Kubernetes or the handler; the core's monitor runs what it
makes.
"""
