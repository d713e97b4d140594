"""The gRPC stubs are generated from the service's proto when the package is built: protoc
with gRPC's Python plugin (Debian's protobuf-compiler and protobuf-compiler-grpc) writes
brenier/v1/brenier_pb2.py and brenier_pb2_grpc.py. The proto is read from ../../proto (the
repository's), or from $BRENIER_PROTO_DIR."""
import os
import shutil
import subprocess

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))


def generate_stubs():
    proto_dir = os.environ.get("BRENIER_PROTO_DIR") or os.path.join(HERE, "..", "..", "proto")
    source = os.path.join(proto_dir, "brenier", "v1", "brenier.proto")
    if not os.path.exists(source):
        raise SystemExit(f"brenier: cannot find {source} (build from the repository, or set BRENIER_PROTO_DIR)")
    protoc = shutil.which("protoc")
    plugin = shutil.which("grpc_python_plugin")
    if not protoc or not plugin:
        raise SystemExit("brenier: protoc and grpc_python_plugin are needed (apt-get install protobuf-compiler "
                         "protobuf-compiler-grpc)")
    subprocess.run([protoc, f"--proto_path={proto_dir}", f"--python_out={HERE}", f"--grpc_python_out={HERE}",
                    f"--plugin=protoc-gen-grpc_python={plugin}", "brenier/v1/brenier.proto"], check=True)
    init = os.path.join(HERE, "brenier", "v1", "__init__.py")
    if not os.path.exists(init):
        open(init, "w").close()


class BuildWithStubs(build_py):
    def run(self):
        generate_stubs()
        super().run()


# Also before the metadata step, which already needs the package brenier.v1 to exist.
generate_stubs()
setup(cmdclass={"build_py": BuildWithStubs})
