"""The package's own PEP 517 build backend, so that `pip install ./clients/python` needs no
download: pip's isolated build environment is empty (`requires = []`), and this module
builds the wheel with the standard library alone. Before packing, the gRPC stubs are
generated from the service's proto by protoc with gRPC's Python plugin (Debian's
protobuf-compiler and protobuf-compiler-grpc) into brenier/v1/. The proto is read from
$BRENIER_PROTO_DIR, ./proto (an sdist) or ../../proto (the repository)."""
import base64
import hashlib
import io
import os
import shutil
import subprocess
import tarfile
import tomllib
import zipfile

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PROTO = os.path.join("brenier", "v1", "brenier.proto")


def _project():
    with open(os.path.join(HERE, "pyproject.toml"), "rb") as f:
        return tomllib.load(f)["project"]


def _proto_dir():
    for d in (os.environ.get("BRENIER_PROTO_DIR"), os.path.join(HERE, "proto"), os.path.join(HERE, "..", "..", "proto")):
        if d and os.path.exists(os.path.join(d, PROTO)):
            return d
    raise RuntimeError(f"brenier: cannot find {PROTO} (build from the repository, or set BRENIER_PROTO_DIR)")


def _generate_stubs():
    protoc, plugin = shutil.which("protoc"), shutil.which("grpc_python_plugin")
    if not protoc or not plugin:
        raise RuntimeError("brenier: protoc and grpc_python_plugin are needed "
                           "(apt-get install protobuf-compiler protobuf-compiler-grpc)")
    subprocess.run([protoc, f"--proto_path={_proto_dir()}", f"--python_out={HERE}", f"--grpc_python_out={HERE}",
                    f"--plugin=protoc-gen-grpc_python={plugin}", PROTO.replace(os.sep, "/")], check=True)
    open(os.path.join(HERE, "brenier", "v1", "__init__.py"), "a").close()


def _metadata():
    p = _project()
    lines = ["Metadata-Version: 2.1", f"Name: {p['name']}", f"Version: {p['version']}", f"Summary: {p['description']}",
             f"Requires-Python: {p['requires-python']}"]
    lines += [f"Requires-Dist: {d}" for d in p.get("dependencies", [])]
    for extra, deps in p.get("optional-dependencies", {}).items():
        lines.append(f"Provides-Extra: {extra}")
        lines += [f'Requires-Dist: {d}; extra == "{extra}"' for d in deps]
    with open(os.path.join(HERE, p["readme"]), encoding="utf-8") as f:
        lines += ["Description-Content-Type: text/markdown", "", f.read()]
    return "\n".join(lines) + "\n"


def _dist_info():
    p = _project()
    return f"{p['name']}-{p['version']}.dist-info"


WHEEL = "Wheel-Version: 1.0\nGenerator: brenier_build\nRoot-Is-Purelib: true\nTag: py3-none-any\n"


def get_requires_for_build_wheel(config_settings=None):
    return []


def get_requires_for_build_sdist(config_settings=None):
    return []


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    d = os.path.join(metadata_directory, _dist_info())
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "METADATA"), "w", encoding="utf-8") as f:
        f.write(_metadata())
    with open(os.path.join(d, "WHEEL"), "w") as f:
        f.write(WHEEL)
    return _dist_info()


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    """A pure-Python wheel of brenier/ (with the generated stubs) and its dist-info."""
    _generate_stubs()
    p = _project()
    name = f"{p['name']}-{p['version']}-py3-none-any.whl"
    files = []
    for root, _, names in os.walk(os.path.join(HERE, "brenier")):
        for n in sorted(names):
            if n.endswith(".py"):
                path = os.path.join(root, n)
                files.append((os.path.relpath(path, HERE).replace(os.sep, "/"), open(path, "rb").read()))
    info = _dist_info()
    files += [(f"{info}/METADATA", _metadata().encode()), (f"{info}/WHEEL", WHEEL.encode())]
    record = []
    with zipfile.ZipFile(os.path.join(wheel_directory, name), "w", zipfile.ZIP_DEFLATED) as z:
        for arcname, data in sorted(files):
            z.writestr(arcname, data)
            digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
            record.append(f"{arcname},sha256={digest},{len(data)}")
        record.append(f"{info}/RECORD,,")
        z.writestr(f"{info}/RECORD", "\n".join(record) + "\n")
    return name


def build_sdist(sdist_directory, config_settings=None):
    """The sources with the proto beside them (./proto), so that the sdist builds alone."""
    p = _project()
    base = f"{p['name']}-{p['version']}"
    name = f"{base}.tar.gz"
    with tarfile.open(os.path.join(sdist_directory, name), "w:gz") as t:
        for rel in ["pyproject.toml", p["readme"], "build_backend/brenier_build.py", "brenier/__init__.py",
                    "brenier/client.py"]:
            t.add(os.path.join(HERE, rel), f"{base}/{rel}")
        t.add(os.path.join(_proto_dir(), PROTO), f"{base}/proto/{PROTO}")
        info = tarfile.TarInfo(f"{base}/PKG-INFO")
        data = _metadata().encode()
        info.size = len(data)
        t.addfile(info, io.BytesIO(data))
    return name
