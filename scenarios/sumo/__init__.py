"""SUMO roundabout scenarios through libsumo (optional extra ``pirl_sim[sumo]``)."""
