"""The brenier service from Python: meshes in (file paths, mesh ids or (V, F) numpy arrays),
jobs run on the server, results out as numpy arrays and dicts."""
import hashlib
import io
import json
import os
import re
import sys
import uuid

import grpc
import numpy as np

from .v1 import brenier_pb2 as pb
from .v1 import brenier_pb2_grpc as rpc

_CHUNK = 65536
_ID = re.compile(r"^[0-9a-f]{64}$")
_DOMAINS = {"disk": pb.DISK, "sphere": pb.SPHERE}
_MAP_METHODS = {"conformal": pb.CONFORMAL, "area-preserving": pb.AREA_PRESERVING}
_DISTANCES = {"wasserstein": pb.WASSERSTEIN, "omt-linear": pb.OMT_LINEAR}
# google.rpc.Code numbers of a job's error, as grpc.StatusCode.
_CODES = {c.value[0]: c for c in grpc.StatusCode}


class BrenierError(Exception):
    """A refused call or a failed job: `code` is the grpc.StatusCode (INVALID_ARGUMENT for a bad
    mesh or option, ABORTED for a solver that did not converge, CANCELLED, ...), `message` the
    server's one-line explanation, `job_id` the job's id where there is one."""

    def __init__(self, code, message, job_id=None):
        super().__init__(f"{code.name}: {message}")
        self.code = code
        self.message = message
        self.job_id = job_id


class NamedMatrix(np.ndarray):
    """A distance matrix: a float ndarray with `names`, the shapes of its rows and columns."""

    def __new__(cls, values, names):
        obj = np.asarray(values, dtype=float).view(cls)
        obj.names = list(names)
        return obj

    def __array_finalize__(self, obj):
        self.names = getattr(obj, "names", None)


class MapResult:
    """A map of a surface: `positions` (V x 3, the surface that was mapped, as the service
    cleaned it; None for a sphere map, whose artifact holds only the sphere's points), `faces` (F x 3),
    `uv` (V x 2 on the unit disk; None on the sphere) or `sphere` (V x 3 on the unit sphere),
    `image` (V x 3 either way), `quality` and the whole `report` (dicts), `job_id`."""

    def __init__(self, job_id, positions, faces, image, disk, report):
        self.job_id = job_id
        self.positions = positions
        self.faces = faces
        self.image = image
        self.disk = disk
        self.uv = image[:, :2] if disk else None
        self.sphere = None if disk else image
        self.report = report
        self.quality = report.get("quality", {})

    def __repr__(self):
        where = "disk" if self.disk else "sphere"
        return f"<MapResult {self.report.get('method')} onto the {where}: {len(self.positions)} vertices, job {self.job_id}>"


class DistanceResult:
    """A shape distance: `distance` (float), the `report` (dict), `job_id`."""

    def __init__(self, job_id, distance, report):
        self.job_id = job_id
        self.distance = distance
        self.report = report

    def __float__(self):
        return float(self.distance)

    def __repr__(self):
        return f"<DistanceResult {self.distance!r}, job {self.job_id}>"


class RegisterResult:
    """A registration of a source surface onto a target (Alg. 7). Per source vertex, in the
    source's vertex order: `source_vertex`, `target_face`, `target_vertices` (n x 3),
    `bary` (n x 3, barycentric coordinates in that face) and `positions` (n x 3, the point on
    the target); `morph` is (V, F), the source's faces over those points; `report` (dict) and
    `job_id`."""

    def __init__(self, job_id, table, morph, report):
        self.job_id = job_id
        self.source_vertex = table[:, 0].astype(np.int64)
        self.target_face = table[:, 1].astype(np.int64)
        self.target_vertices = table[:, 2:5].astype(np.int64)
        self.bary = table[:, 5:8]
        self.positions = table[:, 8:11]
        self.morph = morph
        self.report = report

    def __repr__(self):
        return (f"<RegisterResult {self.report.get('method')} on the {self.report.get('domain')}: "
                f"{len(self.source_vertex)} source vertices, job {self.job_id}>")


def _off_bytes(vertices, faces):
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError("a mesh as arrays is (V, F): V of shape (n, 3), F of shape (m, 3) with integer indices")
    out = io.StringIO()
    out.write(f"OFF\n{len(v)} {len(f)} 0\n")
    np.savetxt(out, v, fmt="%.17g")
    np.savetxt(out, np.hstack([np.full((len(f), 1), 3), f]), fmt="%d")
    return out.getvalue().encode()


def _parse_obj(data):
    """Positions, per-vertex vt (or None) and faces of an OBJ as the service writes it."""
    v, vt, f = [], [], []
    for line in data.decode().splitlines():
        if line.startswith("v "):
            v.append(line.split()[1:4])
        elif line.startswith("vt "):
            vt.append(line.split()[1:3])
        elif line.startswith("f "):
            f.append([int(c.split("/")[0]) - 1 for c in line.split()[1:]])
    return (np.array(v, dtype=float), np.array(vt, dtype=float) if vt else None, np.array(f, dtype=np.int64))


class _Progress:
    """The progress callback of watch(): a callable taking each JobEvent, True for a tqdm bar
    (a line per stage on stderr without tqdm), or None."""

    def __init__(self, progress):
        self.fn = progress if callable(progress) else None
        self.bar = None
        self.stage = None
        if progress is True:
            try:
                from tqdm import tqdm
                self.bar = tqdm(total=1000, unit="‰", leave=False)
            except ImportError:
                self.fn = self._line

    def _line(self, e):
        if e.stage != self.stage:
            self.stage = e.stage
            print(f"brenier: {e.stage} ({100 * e.fraction:.0f} %)", file=sys.stderr)

    def __call__(self, e):
        if self.bar is not None:
            self.bar.set_description(e.stage or pb.JobState.Name(e.state).lower())
            self.bar.update(max(0, int(1000 * e.fraction) - self.bar.n))
        if self.fn:
            self.fn(e)

    def close(self):
        if self.bar is not None:
            self.bar.close()


class Client:
    """A connection to brenierd.

    server: "host:port" (default $BRENIER_SERVER, else localhost:50051); token: the bearer
    token of a server started with --tokens (default $BRENIER_TOKEN); tls: False, True (the
    system's roots) or the path of a PEM file of root certificates; client_cert: (cert.pem,
    key.pem) for a server that asks for client certificates; timeout: seconds per call
    (None: no limit; waiting for a job is never limited)."""

    def __init__(self, server=None, token=None, tls=False, client_cert=None, timeout=None):
        self.server = server or os.environ.get("BRENIER_SERVER") or "localhost:50051"
        self.token = token if token is not None else os.environ.get("BRENIER_TOKEN")
        self.timeout = timeout
        if tls or client_cert:
            roots = open(tls, "rb").read() if isinstance(tls, (str, os.PathLike)) else None
            chain = key = None
            if client_cert:
                chain, key = (open(p, "rb").read() for p in client_cert)
            credentials = grpc.ssl_channel_credentials(root_certificates=roots, private_key=key, certificate_chain=chain)
            self._channel = grpc.secure_channel(self.server, credentials)
        else:
            self._channel = grpc.insecure_channel(self.server)
        self._stub = rpc.BrenierStub(self._channel)

    def close(self):
        self._channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ---- calls ------------------------------------------------------------------------------

    def _metadata(self):
        return [("authorization", f"Bearer {self.token}")] if self.token else None

    def _call(self, method, request, stream=False, timeout=-1):
        try:
            response = method(request, metadata=self._metadata(), timeout=self.timeout if timeout == -1 else timeout)
            return list(response) if stream else response
        except grpc.RpcError as e:
            raise BrenierError(e.code(), e.details()) from None

    # ---- meshes -----------------------------------------------------------------------------

    def upload(self, mesh, name=None):
        """Uploads a mesh file (path) or a (V, F) pair of arrays; returns its pb.Mesh record
        (id, name, vertices, faces, topology_class, warnings, ...). Uploading the same bytes
        again returns the same id."""
        if isinstance(mesh, (str, os.PathLike)):
            data = open(mesh, "rb").read()
            name = name or os.path.basename(mesh)
            fmt = ""
        else:
            vertices, faces = mesh
            data = _off_bytes(vertices, faces)
            name = name or "arrays.off"
            fmt = "off"
        header = pb.UploadMeshRequest.Header(name=name, format=fmt, size_bytes=len(data),
                                             sha256=hashlib.sha256(data).hexdigest())

        def messages():
            yield pb.UploadMeshRequest(header=header)
            for k in range(0, len(data), _CHUNK):
                yield pb.UploadMeshRequest(chunk=data[k:k + _CHUNK])

        return self._call(self._stub.UploadMesh, messages())

    def mesh_id(self, mesh):
        """The id of a mesh given as an id (64 hex digits), a file path or (V, F) arrays,
        uploading it when needed."""
        if isinstance(mesh, str) and _ID.match(mesh) and not os.path.exists(mesh):
            return mesh
        if isinstance(mesh, (str, os.PathLike)) and not os.path.exists(mesh):
            raise BrenierError(grpc.StatusCode.INVALID_ARGUMENT, f"no file {mesh} (and not a mesh id)")
        return self.upload(mesh).id

    def meshes(self):
        """Every mesh of this tenant (pb.Mesh records)."""
        out, token = [], ""
        while True:
            r = self._call(self._stub.ListMeshes, pb.ListMeshesRequest(page_size=1000, page_token=token))
            out.extend(r.meshes)
            token = r.next_page_token
            if not token:
                return out

    def delete(self, mesh_id):
        self._call(self._stub.DeleteMesh, pb.DeleteMeshRequest(id=mesh_id))

    # ---- jobs -------------------------------------------------------------------------------

    def submit(self, request_id=None, **spec):
        """Submits a job (map=pb.MapSpec, distance=pb.DistanceSpec, matrix=pb.MatrixSpec or
        registration=pb.RegisterSpec); returns its pb.Job at once."""
        return self._call(self._stub.SubmitJob, pb.SubmitJobRequest(request_id=request_id or uuid.uuid4().hex, **spec))

    def job(self, job_id):
        return self._call(self._stub.GetJob, pb.GetJobRequest(id=job_id))

    def cancel(self, job_id):
        """Asks the server to stop the job; returns its pb.Job."""
        return self._call(self._stub.CancelJob, pb.CancelJobRequest(id=job_id))

    def watch(self, job_id, progress=None):
        """Follows the job to its end, calling `progress` with each pb.JobEvent (stage,
        fraction, iteration, residual); progress=True draws a tqdm bar. Returns the finished
        pb.Job; raises BrenierError for a job that failed or was cancelled."""
        shown = _Progress(progress)
        try:
            stream = self._stub.WatchJob(pb.WatchJobRequest(id=job_id), metadata=self._metadata())
            for e in stream:
                shown(e)
        except grpc.RpcError as e:
            raise BrenierError(e.code(), e.details(), job_id) from None
        finally:
            shown.close()
        job = self.job(job_id)
        if job.state == pb.SUCCEEDED:
            return job
        if job.state == pb.CANCELLED:
            raise BrenierError(grpc.StatusCode.CANCELLED, job.error.message or "cancelled", job_id)
        code = _CODES.get(job.error.code, grpc.StatusCode.UNKNOWN)
        raise BrenierError(code, job.error.message or pb.JobState.Name(job.state), job_id)

    def result(self, job_id, artifact=""):
        """The bytes of a finished job's artifact (mesh, report, matrix, matrix.npy,
        preview.png, preview.svg, report.html; empty: the main one), checked against its
        size and SHA-256."""
        chunks = self._call(self._stub.GetResult, pb.GetResultRequest(id=job_id, artifact=artifact), stream=True)
        meta = chunks[0].artifact
        data = b"".join(c.chunk for c in chunks[1:])
        if len(data) != meta.size_bytes or hashlib.sha256(data).hexdigest() != meta.sha256:
            raise BrenierError(grpc.StatusCode.DATA_LOSS, f"artifact {meta.name} arrived damaged", job_id)
        return data

    def _report(self, job_id):
        return json.loads(self.result(job_id, "report"))

    # ---- computations -----------------------------------------------------------------------

    def map(self, mesh, domain="disk", method="conformal", *, t=0.0, tolerance=0.0, cut_hole=False, weights=None,
            allow_flips=False, max_iterations=0, refine=True, refine_tolerance=None, progress=None):
        """Maps a surface onto the unit disk or sphere (conformal: Alg. 1; area-preserving:
        the conformal map, then optimal transport, Alg. 3, then the face-by-face area
        refinement unless refine=False) and waits for it. refine_tolerance=(mean, p95): the
        refinement's stop on |log area ratio| (None: the server's, 0.01 and 0.05)."""
        mean_tol, p95_tol = refine_tolerance if refine_tolerance is not None else (0.0, 0.0)
        spec = pb.MapSpec(mesh=self.mesh_id(mesh), domain=_pick(_DOMAINS, domain, "domain"),
                          method=_pick(_MAP_METHODS, method, "method"), t=t, tolerance=tolerance, cut_hole=cut_hole,
                          weights=list(weights) if weights is not None else [], allow_flips=allow_flips,
                          max_iterations=max_iterations, no_refine=not refine, refine_mean_tolerance=mean_tol,
                          refine_p95_tolerance=p95_tol, output_format="obj")
        job = self.watch(self.submit(map=spec).id, progress)
        positions, vt, faces = _parse_obj(self.result(job.id, "mesh"))
        disk = domain == "disk"
        if disk:
            image = np.hstack([vt, np.zeros((len(vt), 1))])
        else:
            image, positions = positions, None
        report = self._report(job.id)
        return MapResult(job.id, positions, faces, image, disk, report)

    def distance(self, a, b, method="wasserstein", domain="disk", *, cut_hole=False, tolerance=0.0,
                 exact_rotation=False, progress=None):
        """The shape distance of two surfaces (Alg. 5, Def. 2.24)."""
        spec = pb.DistanceSpec(a=self.mesh_id(a), b=self.mesh_id(b), method=_pick(_DISTANCES, method, "method"),
                               domain=_pick(_DOMAINS, domain, "domain"), cut_hole=cut_hole,
                               wasserstein=pb.WassersteinOptions(tolerance=tolerance, exact_rotation=exact_rotation))
        job = self.watch(self.submit(distance=spec).id, progress)
        return DistanceResult(job.id, job.result.distance, self._report(job.id))

    def matrix(self, meshes, method="wasserstein", domain="disk", *, cut_hole=False, tolerance=0.0, progress=None):
        """The distance matrix over meshes: a NamedMatrix (ndarray with .names, the meshes'
        names in order)."""
        ids = [self.mesh_id(m) for m in meshes]
        spec = pb.MatrixSpec(meshes=ids, method=_pick(_DISTANCES, method, "method"),
                             domain=_pick(_DOMAINS, domain, "domain"), cut_hole=cut_hole,
                             wasserstein=pb.WassersteinOptions(tolerance=tolerance))
        job = self.watch(self.submit(matrix=spec).id, progress)
        values = np.load(io.BytesIO(self.result(job.id, "matrix.npy")), allow_pickle=False)
        return NamedMatrix(values, self._report(job.id)["shapes"])


    def register(self, source, target, domain="disk", method="area-preserving", *, landmarks=None, cut_hole=False,
                 tolerance=0.0, max_iterations=0, harmonic_only=False, isometric_sphere=False, progress=None):
        """Registers `source` onto `target` (Alg. 7: f = phi2^-1 o g o phi1, through their
        area-preserving or conformal maps) and waits for it. `landmarks`: a pair of
        sequences of input vertex numbers, (source's, target's), paired by order.
        `harmonic_only`: keep g as Alg. 7 makes it, without moving it toward an isometry of the
        two surfaces; `isometric_sphere`: on the sphere's conformal route, move it so too (the
        default on the disk and on the sphere's area-preserving route)."""
        src, tgt = ([], []) if landmarks is None else (list(landmarks[0]), list(landmarks[1]))
        spec = pb.RegisterSpec(source=self.mesh_id(source), target=self.mesh_id(target),
                               domain=_pick(_DOMAINS, domain, "domain"), method=_pick(_MAP_METHODS, method, "method"),
                               cut_hole=cut_hole, source_landmarks=src, target_landmarks=tgt, tolerance=tolerance,
                               max_iterations=max_iterations, output_format="obj", harmonic_only=harmonic_only,
                               isometric_sphere=isometric_sphere)
        job = self.watch(self.submit(registration=spec).id, progress)
        csv = self.result(job.id, "correspondence").decode()
        table = np.loadtxt(io.StringIO(csv), delimiter=",", skiprows=1, ndmin=2)
        positions, _, faces = _parse_obj(self.result(job.id, "morph"))
        return RegisterResult(job.id, table, (positions, faces), self._report(job.id))


def _pick(table, value, what):
    if value not in table:
        raise BrenierError(grpc.StatusCode.INVALID_ARGUMENT, f"{what} '{value}' is not one of {', '.join(table)}")
    return table[value]
