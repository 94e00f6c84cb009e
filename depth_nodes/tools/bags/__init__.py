"""Bags: reading and writing them (io), playing and recording them in a live graph (live),
running the nodes over them offline (process), converting, generating and importing them."""
