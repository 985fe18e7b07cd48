# dolfinx_universal on the official DOLFINx 0.11 image: installs the package and runs the tests.
#
#   docker build -t dolfinx_universal .
#   docker run --rm dolfinx_universal                      # the test suite (serial and MPI)
#   docker run --rm -v $PWD/out:/work/out dolfinx_universal python3 demos/quality.py --out out
FROM ghcr.io/fenics/dolfinx/dolfinx:v0.11.0

WORKDIR /work
COPY . /work
# DOLFINx, basix, ufl, mpi4py and petsc4py come with the image: do not install the PyPI wheel.
# Installed as users install it (built into site-packages, not editable): the command line
# and the demos run the installed package. The tests, run from /work, import the same
# sources from the tree.
RUN python3 -m pip install --no-cache-dir ".[test]"
ENV OMP_NUM_THREADS=1 MPLBACKEND=Agg
# The suite as .ci/test runs it, with the image's own MPI.
CMD ["bash", "-c", "python3 -m pytest -q && mpirun -n 2 python3 -m pytest -q -m mpi -p no:cacheprovider && mpirun -n 3 python3 -m pytest -q -m mpi -p no:cacheprovider"]
