"""Planning: which poses a session measures and how it moves there. The plan request,
the built-in arm's and wrist's plans (in rounds, from what was measured), a robot file's
serial plan, the D-optimal pose design and the safety envelope that watches each move.
Imports fitting/ (start values, pose counts), outputs/ and recording/."""
