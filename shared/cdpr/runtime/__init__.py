"""The Zenoh runtime: sessions and configs (:mod:`.transport`), the node base and its serve loop
(:mod:`.service`), the node registry, ``python -m cdpr_<name>`` (:mod:`.main`) and the remote-controller
SDK (:mod:`.client`). The only part of :mod:`cdpr` that imports Zenoh."""
