// The smallest use of brenier::Client: upload a mesh, map it onto the disk, save the result.
//   brenier-client-example MESH OUT.obj [HOST:PORT]
#include <cstdio>

#include "client.hpp"

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s MESH OUT.obj [HOST:PORT]\n", argv[0]);
    return 2;
  }
  brenier::client::Options options;
  if (argc > 3) options.server = argv[3];
  try {
    brenier::client::Client client(options);
    const brenier::v1::Mesh mesh = client.upload(argv[1]);
    brenier::v1::SubmitJobRequest request;
    request.mutable_map()->set_mesh(mesh.id());
    request.mutable_map()->set_domain(brenier::v1::DISK);
    const brenier::v1::Job job = client.submit(request);
    const brenier::v1::Job done = client.watch(job.id(), [](const brenier::v1::JobEvent& e) {
      std::printf("%s %.0f%%\n", e.stage().c_str(), 100 * e.fraction());
    });
    if (done.state() != brenier::v1::SUCCEEDED) {
      std::fprintf(stderr, "job failed: %s\n", done.error().message().c_str());
      return 3;
    }
    client.download(done.id(), argv[2]);
    std::printf("wrote %s\n", argv[2]);
  } catch (const brenier::client::Error& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 0;
}
