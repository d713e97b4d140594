// The database the service tests run brenierd on. Empty (SQLite in the data directory,
// brenierd's default) unless ctest runs a suite's PostgreSQL variant ("pg." tests): then
// BRENIER_TEST_PG names the file where the fixture (tests/service/postgres.sh) wrote the URL
// of the PostgreSQL 15 it started, and each data directory gets a database of its own,
// created on first use (so a restarted server finds its rows, and tests never share any).
#pragma once

#include <libpq-fe.h>

#include <cstdlib>
#include <fstream>
#include <stdexcept>
#include <string>

#include "common/hash.hpp"

namespace brenier::test {

inline std::string test_database(const std::string& data_dir) {
  const char* file = std::getenv("BRENIER_TEST_PG");
  if (!file || !*file) return "";
  std::ifstream in(file);
  std::string admin;
  if (!(in >> admin)) throw std::runtime_error(std::string("BRENIER_TEST_PG: cannot read ") + file);
  const std::string name = "t" + sha256_hex(data_dir).substr(0, 20);
  PGconn* c = PQconnectdb(admin.c_str());
  if (PQstatus(c) != CONNECTION_OK) {
    const std::string why = PQerrorMessage(c);
    PQfinish(c);
    throw std::runtime_error("the test PostgreSQL is not reachable: " + why);
  }
  PGresult* r = PQexec(c, ("CREATE DATABASE " + name).c_str());
  const char* state = PQresultErrorField(r, PG_DIAG_SQLSTATE);
  const bool ok = PQresultStatus(r) == PGRES_COMMAND_OK || (state && std::string(state) == "42P04");  // exists
  const std::string why = PQresultErrorMessage(r);
  PQclear(r);
  PQfinish(c);
  if (!ok) throw std::runtime_error("cannot create the test database " + name + ": " + why);
  return admin.substr(0, admin.rfind('/') + 1) + name;
}

}  // namespace brenier::test
