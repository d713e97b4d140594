"""The wire contract outside our own client: Python stubs generated from proto/ by protoc's
grpc python plugin (Debian's protobuf-compiler-grpc), run with Debian's python3-grpcio,
upload a mesh and run a map job on a live brenierd.
Usage: test_python_client.py BRENIERD PROTO_DIR WORK_DIR"""
import hashlib
import os
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from servertest import Server, check, finish, grid_off  # noqa: E402

brenierd, proto_dir, work = sys.argv[1:4]
os.makedirs(work, exist_ok=True)
gen = os.path.join(work, "gen")
os.makedirs(gen, exist_ok=True)
subprocess.run(["protoc", f"--proto_path={proto_dir}", f"--python_out={gen}", f"--grpc_out={gen}",
                "--plugin=protoc-gen-grpc=/usr/bin/grpc_python_plugin", "brenier/v1/brenier.proto"], check=True)
sys.path.insert(0, gen)
import grpc  # noqa: E402
from brenier.v1 import brenier_pb2 as pb  # noqa: E402
from brenier.v1 import brenier_pb2_grpc as rpc  # noqa: E402

server = Server(brenierd, work)
try:
    stub = rpc.BrenierStub(grpc.insecure_channel(server.address))
    data = open(grid_off(os.path.join(work, "grid.off"), 20, bump=0.4), "rb").read()
    sha = hashlib.sha256(data).hexdigest()

    def upload(payload, declared_sha, size=None):
        def messages():
            yield pb.UploadMeshRequest(header=pb.UploadMeshRequest.Header(
                name="grid.off", format="off", size_bytes=len(payload) if size is None else size, sha256=declared_sha))
            for k in range(0, len(payload), 65536):
                yield pb.UploadMeshRequest(chunk=payload[k:k + 65536])
        return stub.UploadMesh(messages())

    mesh = upload(data, sha)
    check(mesh.id == sha, "the mesh id is the SHA-256 of the bytes")
    check(mesh.vertices == 400 and mesh.faces == 2 * 19 * 19, f"vertices and faces: {mesh.vertices} {mesh.faces}")
    check(mesh.topology_class == pb.TOPOLOGICAL_DISK, "a grid is a topological disk")
    try:
        upload(data, "0" * 64)
        check(False, "a wrong SHA-256 is refused")
    except grpc.RpcError as e:
        check(e.code() == grpc.StatusCode.INVALID_ARGUMENT and "SHA-256" in e.details(), f"wrong SHA-256: {e.code()} {e.details()}")

    job = stub.SubmitJob(pb.SubmitJobRequest(request_id="py-1", map=pb.MapSpec(
        mesh=mesh.id, domain=pb.DISK, method=pb.AREA_PRESERVING)))
    check(job.state in (pb.QUEUED, pb.RUNNING), "submitted")
    events = list(stub.WatchJob(pb.WatchJobRequest(id=job.id)))
    check(events[-1].state == pb.SUCCEEDED, f"the watch ends with SUCCEEDED ({len(events)} events)")
    check(any(e.stage == "omt" and e.iteration > 0 for e in events), "Newton iterations of the transport were streamed")
    fractions = [e.fraction for e in events]
    check(fractions == sorted(fractions), "progress never goes backwards")
    chunks = list(stub.GetResult(pb.GetResultRequest(id=job.id)))
    meta = chunks[0].artifact
    body = b"".join(c.chunk for c in chunks[1:])
    check(meta.name == "mesh" and len(body) == meta.size_bytes and hashlib.sha256(body).hexdigest() == meta.sha256,
          "the result arrives whole, as its metadata says")
    text = body.decode()
    uv = [tuple(map(float, l.split()[1:3])) for l in text.splitlines() if l.startswith("vt ")]
    check(len(uv) == 400 and all(u * u + v * v <= 1 + 1e-9 for u, v in uv), "400 texture coordinates in the unit disk")
    report = b"".join(c.chunk for c in list(stub.GetResult(pb.GetResultRequest(id=job.id, artifact="report")))[1:])
    import json
    rep = json.loads(report)
    check(rep["omt"]["converged"] and rep["omt"]["max_relative_area_error"] <= 1e-8, "the transport converged to 1e-8")
    check(rep["quality"]["flipped_faces"] == 0, "no folded face")
    again = stub.SubmitJob(pb.SubmitJobRequest(request_id="py-1", map=pb.MapSpec(
        mesh=mesh.id, domain=pb.DISK, method=pb.AREA_PRESERVING)))
    check(again.id == job.id, "the same request_id returns the same job")
    # The refinement's stop, stated in the spec, reaches the engine and comes back in the report.
    stop = stub.SubmitJob(pb.SubmitJobRequest(request_id="py-2", map=pb.MapSpec(
        mesh=mesh.id, domain=pb.DISK, method=pb.AREA_PRESERVING, refine_mean_tolerance=0.03, refine_p95_tolerance=0.2)))
    check(list(stub.WatchJob(pb.WatchJobRequest(id=stop.id)))[-1].state == pb.SUCCEEDED, "the stated stop's job succeeds")
    rep = json.loads(b"".join(c.chunk for c in list(stub.GetResult(pb.GetResultRequest(id=stop.id, artifact="report")))[1:]))
    check(rep["omt"]["refined"]["tolerance"] == {"mean_abs": 0.03, "p95_abs": 0.2}, f"stop echoed: {rep['omt']['refined']}")
    try:
        stub.SubmitJob(pb.SubmitJobRequest(request_id="py-3", map=pb.MapSpec(
            mesh=mesh.id, domain=pb.DISK, method=pb.AREA_PRESERVING, refine_p95_tolerance=float("nan"))))
        check(False, "a NaN stop is refused")
    except grpc.RpcError as e:
        check(e.code() == grpc.StatusCode.INVALID_ARGUMENT and "refine_p95_tolerance" in e.details(),
              f"NaN stop: {e.code()} {e.details()}")
    try:
        list(stub.GetResult(pb.GetResultRequest(id="no-such-job")))
        check(False, "an unknown job is NOT_FOUND")
    except grpc.RpcError as e:
        check(e.code() == grpc.StatusCode.NOT_FOUND, f"unknown job: {e.code()}")
finally:
    rc = server.stop()
    check(rc == 0, f"brenierd stops cleanly on SIGTERM ({rc})")
finish()
