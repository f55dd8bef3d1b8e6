"""Runs: a method fitted to a dataset (:mod:`.fit`), its directory and lock (:mod:`.directory`), and what is
made from a run or from another tool's renders: novel views (:mod:`.novel`), the learned medium as grids
(:mod:`.export`), any folder of renders scored as a bench cell (:mod:`.external`)."""
