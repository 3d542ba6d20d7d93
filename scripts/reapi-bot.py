#!/usr/bin/env python3
"""A small Remote Workers API bot for BuildGrid (issue 17, item 4: remote execution on 127.0.0.1).

What it implements
  * The bot side of google.devtools.remoteworkers.v1test2.Bots as BuildGrid 0.4.4's SQL scheduler
    speaks it (buildgrid/server/bots/service.py, scheduler/impl.py): CreateBotSession, then a loop
    of UpdateBotSession. BuildGrid hands a lease out already ACTIVE (a PENDING one is accepted by
    sending it back ACTIVE); its payload is the REAPI `Action` itself (an Any), or an Action
    `Digest` whose Action is read from the CAS. The bot reports the lease COMPLETED with
    `result` = Any(ActionResult) and `status` = google.rpc.Status; BuildGrid then answers the
    client's Execute and stores the result in the action cache. A command that exits non-zero is
    still status OK with that exit code (REAPI); a failure of the bot itself (a blob missing from
    the CAS, an output that cannot be uploaded) is status INTERNAL, which BuildGrid retries.
  * For each lease: the Action's Command and input root `Directory` tree read from the CAS
    (BatchReadBlobs; ByteStream Read for blobs over 1 MiB), materialised in a fresh temporary
    folder (regular files with their is_executable bit, symlinks, empty folders; file contents
    come from a local blob cache by hard link), the parent folders of the declared outputs
    created, the command run with exactly its `environment_variables`, in its
    `working_directory`, under the Action's timeout (else --action-timeout), in its own process
    group; then the declared `output_files` (and `output_paths`) that exist, and
    `output_directories` as `Tree` messages, plus stdout and stderr, uploaded to the CAS
    (FindMissingBlobs, then BatchUpdateBlobs, ByteStream Write for large blobs), and the
    `ActionResult` filled (exit code, outputs, stdout/stderr digests, worker timestamps).
    A command past its timeout is killed and its lease reported DEADLINE_EXCEEDED; a lease the
    server cancels (dropped from the session) kills its command and is reported CANCELLED.
  * Transient RPC errors of the session calls (UNAVAILABLE, RESOURCE_EXHAUSTED,
    DEADLINE_EXCEEDED, ABORTED) are retried with a growing pause until the deadline; any other
    error of a session stops the whole bot with exit status 1, so a test waiting on it fails
    at once instead of waiting for leases nobody runs.
  * --workers N bot sessions in threads, each with capacity 1 (one lease at a time), so N
    actions run side by side. While a command runs, its session sends keep-alive updates.
  * One JSON line per lease to --log (`"event": "completed"` with lease id, action digest, exit
    code, seconds), and a summary line at the end; the test script counts these.
  * Bounded: the bot stops by itself after --deadline seconds and on SIGTERM/SIGINT (a running
    command's process group is killed); every RPC has a timeout; the channel is plain gRPC to
    the address given (the tests use 127.0.0.1 only).

What it does not implement
  * No sandboxing beyond a fresh input-root folder per action: the command runs as the bot's
    user with the machine's file system, network and tools visible. Only for trusted actions.
  * No platform matching beyond advertising OSFamily=linux and ISA=x86-64 (BuildGrid's dynamic
    property set matches a job whose platform is empty or a subset of these); an action's
    platform properties are not otherwise looked at.
  * No output symlinks reported as symlinks (a symlink output is read through as a file), no
    compression, no partial-execution metadata or log streams, no instance-name wildcards,
    SHA-256 digests only, no retry of a failed CAS call inside a lease (the lease fails INTERNAL
    and BuildGrid retries it, up to the scheduler's max-job-attempts).
  * No limit on the local blob cache (--work/blobs): it lives as long as the --work folder.

Usage (scripts/bazel-remote-exec.sh runs it so):
  reapi-bot.py --server 127.0.0.1:PORT --workers 2 --work DIR --log DIR/bot.jsonl --deadline 420
"""

import argparse
import hashlib
import json
import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import threading
import time
import uuid

import grpc
from google.protobuf import timestamp_pb2

from buildgrid._protos.build.bazel.remote.execution.v2 import remote_execution_pb2 as re_pb2
from buildgrid._protos.build.bazel.remote.execution.v2 import remote_execution_pb2_grpc as re_grpc
from buildgrid._protos.google.bytestream import bytestream_pb2, bytestream_pb2_grpc
from buildgrid._protos.google.devtools.remoteworkers.v1test2 import bots_pb2, bots_pb2_grpc, worker_pb2
from buildgrid._protos.google.rpc import code_pb2, status_pb2

CHUNK = 1 << 20  # ByteStream chunk, and the size above which a blob goes through ByteStream
BATCH = 2 << 20  # bytes per BatchReadBlobs / BatchUpdateBlobs request (BuildGrid's limit: 4 MiB)
RPC_TIMEOUT = 60.0  # seconds for one CAS call
POLL = 20.0  # seconds one UpdateBotSession may wait for work (BuildGrid waits 80% of it)
EMPTY = hashlib.sha256(b"").hexdigest()
TRANSIENT = (
    grpc.StatusCode.UNAVAILABLE,
    grpc.StatusCode.RESOURCE_EXHAUSTED,
    grpc.StatusCode.DEADLINE_EXCEEDED,
    grpc.StatusCode.ABORTED,
)

STOP = threading.Event()
LOG_LOCK = threading.Lock()


def log(path, **fields):
    fields["time"] = round(time.time(), 3)
    line = json.dumps(fields, sort_keys=True)
    with LOG_LOCK:
        if path:
            with open(path, "a") as f:
                f.write(line + "\n")
        print(line, file=sys.stderr, flush=True)


def digest_of(data):
    return re_pb2.Digest(hash=hashlib.sha256(data).hexdigest(), size_bytes=len(data))


def digest_of_file(path):
    h = hashlib.sha256()
    n = 0
    with open(path, "rb") as f:
        while True:
            block = f.read(CHUNK)
            if not block:
                break
            h.update(block)
            n += len(block)
    return re_pb2.Digest(hash=h.hexdigest(), size_bytes=n)


def now_ts():
    ts = timestamp_pb2.Timestamp()
    ts.GetCurrentTime()
    return ts


class BotError(Exception):
    """A failure of the bot (not of the command): the lease is reported INTERNAL (BuildGrid
    retries it)."""


class LeaseEnd(Exception):
    """The command was stopped: a timeout (DEADLINE_EXCEEDED) or a cancelled lease (CANCELLED)."""

    def __init__(self, code, message):
        super().__init__(message)
        self.code = code


class Cas:
    """The CAS and ByteStream of one instance, with a local blob cache on disk."""

    def __init__(self, channel, instance, cache_dir):
        self.instance = instance
        self.cas = re_grpc.ContentAddressableStorageStub(channel)
        self.bytestream = bytestream_pb2_grpc.ByteStreamStub(channel)
        self.cache_dir = cache_dir
        os.makedirs(cache_dir, exist_ok=True)

    def _resource(self, d):
        name = f"blobs/{d.hash}/{d.size_bytes}"
        return f"{self.instance}/{name}" if self.instance else name

    # --- reading

    def read_blobs(self, digests):
        """Bytes of each digest (a dict by hash); raises BotError for a missing blob."""
        out = {EMPTY: b""}
        todo = []
        seen = set()
        for d in digests:
            if d.hash in out or d.hash in seen:
                continue
            seen.add(d.hash)
            if d.size_bytes > CHUNK:
                out[d.hash] = self._read_stream(d)
            else:
                todo.append(d)
        batch, size = [], 0
        for d in todo + [None]:
            if d is None or (batch and size + d.size_bytes > BATCH):
                if batch:
                    resp = self.cas.BatchReadBlobs(
                        re_pb2.BatchReadBlobsRequest(instance_name=self.instance, digests=batch),
                        timeout=RPC_TIMEOUT,
                    )
                    for r in resp.responses:
                        if r.status.code != code_pb2.OK:
                            raise BotError(f"blob {r.digest.hash}/{r.digest.size_bytes}: {r.status.message or r.status.code}")
                        out[r.digest.hash] = r.data
                    missing = [b.hash for b in batch if b.hash not in out]
                    if missing:
                        raise BotError(f"blobs not returned: {missing}")
                batch, size = [], 0
            if d is not None:
                batch.append(d)
                size += d.size_bytes
        for d in digests:
            if hashlib.sha256(out[d.hash]).hexdigest() != d.hash:
                raise BotError(f"blob {d.hash}: contents do not match the digest")
        return out

    def _read_stream(self, d):
        parts = []
        for resp in self.bytestream.Read(
            bytestream_pb2.ReadRequest(resource_name=self._resource(d)), timeout=RPC_TIMEOUT * 4
        ):
            parts.append(resp.data)
        data = b"".join(parts)
        if len(data) != d.size_bytes:
            raise BotError(f"blob {d.hash}: read {len(data)} of {d.size_bytes} bytes")
        return data

    def read_message(self, d, message):
        message.ParseFromString(self.read_blobs([d])[d.hash])
        return message

    def cached_file(self, d, executable):
        """Path of a read-only local copy of blob d (mode 0555 or 0444); fetched if needed."""
        path = os.path.join(self.cache_dir, f"{d.hash}-{d.size_bytes}{'-x' if executable else ''}")
        if not os.path.exists(path):
            self.fill_cache([d], executable)
        return path

    def fill_cache(self, digests, executable):
        need = []
        for d in digests:
            path = os.path.join(self.cache_dir, f"{d.hash}-{d.size_bytes}{'-x' if executable else ''}")
            if not os.path.exists(path):
                need.append(d)
        if not need:
            return
        blobs = self.read_blobs(need)
        for d in need:
            path = os.path.join(self.cache_dir, f"{d.hash}-{d.size_bytes}{'-x' if executable else ''}")
            tmp = f"{path}.{uuid.uuid4().hex}.tmp"
            with open(tmp, "wb") as f:
                f.write(blobs[d.hash])
            os.chmod(tmp, 0o555 if executable else 0o444)
            os.replace(tmp, path)

    # --- writing

    def upload(self, blobs):
        """blobs: {hash: (Digest, bytes or path)}; uploads those the CAS lacks."""
        if not blobs:
            return
        digests = [d for d, _ in blobs.values()]
        missing = []
        for i in range(0, len(digests), 1000):
            resp = self.cas.FindMissingBlobs(
                re_pb2.FindMissingBlobsRequest(instance_name=self.instance, blob_digests=digests[i : i + 1000]),
                timeout=RPC_TIMEOUT,
            )
            missing.extend(resp.missing_blob_digests)
        batch, size = [], 0
        for d in missing + [None]:
            if d is not None and d.size_bytes > CHUNK:
                self._write_stream(d, blobs[d.hash][1])
                continue
            if d is None or (batch and size + d.size_bytes > BATCH):
                if batch:
                    resp = self.cas.BatchUpdateBlobs(
                        re_pb2.BatchUpdateBlobsRequest(instance_name=self.instance, requests=batch),
                        timeout=RPC_TIMEOUT,
                    )
                    for r in resp.responses:
                        if r.status.code != code_pb2.OK:
                            raise BotError(f"upload of {r.digest.hash}: {r.status.message or r.status.code}")
                batch, size = [], 0
            if d is not None:
                batch.append(re_pb2.BatchUpdateBlobsRequest.Request(digest=d, data=self._bytes(blobs[d.hash][1])))
                size += d.size_bytes

    @staticmethod
    def _bytes(src):
        if isinstance(src, (bytes, bytearray)):
            return bytes(src)
        with open(src, "rb") as f:
            return f.read()

    def _write_stream(self, d, src):
        name = f"uploads/{uuid.uuid4()}/blobs/{d.hash}/{d.size_bytes}"
        if self.instance:
            name = f"{self.instance}/{name}"

        def requests():
            if isinstance(src, (bytes, bytearray)):
                chunks = (src[i : i + CHUNK] for i in range(0, max(len(src), 1), CHUNK))
            else:
                chunks = _file_chunks(src)
            offset = 0
            first = True
            pending = None
            for chunk in chunks:
                if pending is not None:
                    yield pending
                pending = bytestream_pb2.WriteRequest(
                    resource_name=name if first else "", write_offset=offset, data=bytes(chunk)
                )
                first = False
                offset += len(chunk)
            if pending is None:
                pending = bytestream_pb2.WriteRequest(resource_name=name, write_offset=0, data=b"")
            pending.finish_write = True
            yield pending

        resp = self.bytestream.Write(requests(), timeout=RPC_TIMEOUT * 4)
        if resp.committed_size != d.size_bytes:
            raise BotError(f"upload of {d.hash}: committed {resp.committed_size} of {d.size_bytes} bytes")


def _file_chunks(path):
    with open(path, "rb") as f:
        while True:
            block = f.read(CHUNK)
            if not block:
                return
            yield block


def _inside(root, rel):
    """root/rel, refusing absolute paths and '..' escapes (a path from the Command or a Directory)."""
    if os.path.isabs(rel):
        raise BotError(f"absolute path in the action: {rel}")
    path = os.path.normpath(os.path.join(root, rel))
    if path != root and not path.startswith(root + os.sep):
        raise BotError(f"path escapes the input root: {rel}")
    return path


def materialize(cas, root_digest, root):
    """Writes the input root tree into the (existing, empty) folder root; returns the file count."""
    directories = {}
    frontier = [root_digest]
    while frontier:
        blobs = cas.read_blobs(frontier)
        nxt = []
        for d in frontier:
            if d.hash in directories:
                continue
            msg = re_pb2.Directory()
            msg.ParseFromString(blobs[d.hash])
            directories[d.hash] = msg
            for sub in msg.directories:
                if sub.digest.hash not in directories:
                    nxt.append(sub.digest)
        frontier = nxt
    # Fetch every file blob up front (batched), then link them into place.
    for executable in (False, True):
        files = [f.digest for m in directories.values() for f in m.files if f.is_executable == executable]
        cas.fill_cache(files, executable)
    count = 0

    def place(d, path):
        nonlocal count
        msg = directories[d.hash]
        for f in msg.files:
            target = _inside(path, f.name)
            src = cas.cached_file(f.digest, f.is_executable)
            try:
                os.link(src, target)
            except OSError:
                shutil.copy2(src, target)
            count += 1
        for s in msg.symlinks:
            os.symlink(s.target, _inside(path, s.name))
        for sub in msg.directories:
            sub_path = _inside(path, sub.name)
            os.mkdir(sub_path)
            place(sub.digest, sub_path)

    place(root_digest, root)
    return count


def collect_tree(path, blobs):
    """A Tree message for the folder path; adds every file and the Tree's Directories to blobs."""
    children = []

    def walk(p):
        msg = re_pb2.Directory()
        for name in sorted(os.listdir(p)):
            full = os.path.join(p, name)
            st = os.stat(full)  # a symlink is followed (read as what it points to)
            if stat.S_ISDIR(st.st_mode):
                sub = walk(full)
                data = sub.SerializeToString()
                d = digest_of(data)
                children.append(sub)
                msg.directories.add(name=name, digest=d)
            elif stat.S_ISREG(st.st_mode):
                d = digest_of_file(full)
                blobs[d.hash] = (d, full)
                msg.files.add(name=name, digest=d, is_executable=bool(st.st_mode & 0o100))
        return msg

    root = walk(path)
    # Children deduplicated by content (a Tree lists each distinct Directory once is enough).
    unique = {}
    for c in children:
        unique.setdefault(c.SerializeToString(), c)
    tree = re_pb2.Tree(root=root, children=list(unique.values()))
    return tree


def execute(cas, action, work_dir, default_timeout, bot_name, on_tick):
    """Runs one Action; returns its ActionResult. on_tick() is called about every second while
    the command runs and returns False if the lease was taken away (the command is then killed)."""
    meta = re_pb2.ExecutedActionMetadata(worker=bot_name)
    meta.input_fetch_start_timestamp.CopyFrom(now_ts())
    command = cas.read_message(action.command_digest, re_pb2.Command())
    root = tempfile.mkdtemp(prefix="action-", dir=work_dir)
    try:
        materialize(cas, action.input_root_digest, root)
        meta.input_fetch_completed_timestamp.CopyFrom(now_ts())
        cwd = _inside(root, command.working_directory) if command.working_directory else root
        os.makedirs(cwd, exist_ok=True)
        outputs = list(command.output_files) + list(command.output_directories) + list(command.output_paths)
        for rel in outputs:
            os.makedirs(os.path.dirname(_inside(cwd, rel)), exist_ok=True)
        for rel in command.output_directories:
            os.makedirs(_inside(cwd, rel), exist_ok=True)
        env = {v.name: v.value for v in command.environment_variables}
        if not command.arguments:
            raise BotError("the Command has no arguments")
        timeout = action.timeout.ToTimedelta().total_seconds() if action.HasField("timeout") else 0
        timeout = timeout or default_timeout
        stdout_path = os.path.join(work_dir, f"{os.path.basename(root)}.stdout")
        stderr_path = os.path.join(work_dir, f"{os.path.basename(root)}.stderr")
        meta.execution_start_timestamp.CopyFrom(now_ts())
        with open(stdout_path, "wb") as out, open(stderr_path, "wb") as err:
            argv0 = command.arguments[0]
            if "/" in argv0 and not os.path.isabs(argv0):
                argv0 = os.path.join(cwd, argv0)
            try:
                proc = subprocess.Popen(
                    [argv0] + list(command.arguments[1:]),
                    cwd=cwd,
                    env=env,
                    stdin=subprocess.DEVNULL,
                    stdout=out,
                    stderr=err,
                    start_new_session=True,
                )
            except OSError as e:
                raise BotError(f"cannot start {command.arguments[0]}: {e}")
            started = time.monotonic()
            exit_code = None
            try:
                while exit_code is None:
                    try:
                        exit_code = proc.wait(timeout=1.0)
                    except subprocess.TimeoutExpired:
                        if STOP.is_set():
                            raise BotError(f"{command.arguments[0]}: the bot is stopping")
                        if time.monotonic() - started > timeout:
                            raise LeaseEnd(code_pb2.DEADLINE_EXCEEDED, f"timed out after {timeout:.0f} s")
                        if not on_tick():
                            raise LeaseEnd(code_pb2.CANCELLED, "the lease was cancelled")
            finally:
                if exit_code is None:  # killed with its process group on any way out
                    try:
                        os.killpg(proc.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                    proc.wait()
        meta.execution_completed_timestamp.CopyFrom(now_ts())
        meta.output_upload_start_timestamp.CopyFrom(now_ts())
        result = re_pb2.ActionResult(exit_code=exit_code)
        blobs = {}
        for rel in sorted(set(command.output_files) | set(command.output_paths)):
            path = _inside(cwd, rel)
            if os.path.isfile(path):
                d = digest_of_file(path)
                blobs[d.hash] = (d, path)
                result.output_files.add(path=rel, digest=d, is_executable=bool(os.stat(path).st_mode & 0o100))
            elif os.path.isdir(path) and rel in command.output_paths:
                tree = collect_tree(path, blobs)
                for sub in [tree.root] + list(tree.children):
                    data = sub.SerializeToString()
                    blobs[digest_of(data).hash] = (digest_of(data), data)
                data = tree.SerializeToString()
                d = digest_of(data)
                blobs[d.hash] = (d, data)
                result.output_directories.add(path=rel, tree_digest=d)
        for rel in sorted(set(command.output_directories)):
            path = _inside(cwd, rel)
            if os.path.isdir(path):
                tree = collect_tree(path, blobs)
                for sub in [tree.root] + list(tree.children):
                    data = sub.SerializeToString()
                    blobs[digest_of(data).hash] = (digest_of(data), data)
                data = tree.SerializeToString()
                d = digest_of(data)
                blobs[d.hash] = (d, data)
                result.output_directories.add(path=rel, tree_digest=d)
        for path, field in ((stdout_path, "stdout_digest"), (stderr_path, "stderr_digest")):
            d = digest_of_file(path)
            blobs[d.hash] = (d, path)
            getattr(result, field).CopyFrom(d)
        cas.upload(blobs)
        meta.output_upload_completed_timestamp.CopyFrom(now_ts())
        result.execution_metadata.CopyFrom(meta)
        return result
    finally:
        for p in (root,):
            _remove_tree(p)
        for suffix in (".stdout", ".stderr"):
            try:
                os.unlink(os.path.join(work_dir, os.path.basename(root) + suffix))
            except FileNotFoundError:
                pass


def _remove_tree(path):
    def onerror(func, p, _exc):
        try:
            os.chmod(os.path.dirname(p), 0o755)
            os.chmod(p, 0o755)
            func(p)
        except OSError:
            pass

    shutil.rmtree(path, onerror=onerror)


class Bot(threading.Thread):
    """One bot session with capacity 1."""

    def __init__(self, index, args, channel, cas):
        super().__init__(name=f"bot-{index}", daemon=True)
        self.args = args
        self.stub = bots_pb2_grpc.BotsStub(channel)
        self.cas = cas
        self.bot_id = f"{socket.gethostname()}-{os.getpid()}-{index}"
        self.leases_done = 0
        self.failures = 0
        self.retries = 0
        self.error = None
        self.session = None
        self.lock = threading.Lock()

    def _worker(self):
        w = worker_pb2.Worker()
        dev = w.devices.add(handle=self.bot_id)
        dev.properties.add(key="OSFamily", value="linux")
        dev.properties.add(key="ISA", value="x86-64")
        w.configs.add(key="capacity", value="1")
        return w

    def _remaining(self):
        return self.args.deadline_at - time.monotonic()

    def _call(self, method, request, timeout):
        """One RPC that gives up when the bot stops; None then. Transient errors (the server busy
        or restarting, a lost answer) are retried with a growing pause until the deadline: the
        session sent again is unchanged, so a COMPLETED report is repeated, which BuildGrid
        accepts (a lease it already closed is skipped)."""
        pause = 0.2
        while True:
            fut = method.future(request, timeout=timeout)
            while not fut.done():
                if STOP.is_set() or self._remaining() <= 0:
                    fut.cancel()
                    return None
                time.sleep(0.02)
            try:
                return fut.result()
            except grpc.RpcError as e:
                if e.code() not in TRANSIENT or self._remaining() <= pause:
                    raise
                self.retries += 1
                log(self.args.log, event="retry", bot=self.bot_id, code=e.code().name, details=e.details())
                if STOP.wait(pause):
                    return None
                pause = min(pause * 2, 5.0)

    def _update(self, timeout):
        """UpdateBotSession with the current session; keeps the answer. False when stopping."""
        answer = self._call(
            self.stub.UpdateBotSession,
            bots_pb2.UpdateBotSessionRequest(name=self.session.name, bot_session=self.session),
            timeout,
        )
        if answer is None:
            return False
        self.session = answer
        return True

    def run(self):
        try:
            self._run()
        except Exception as e:  # noqa: BLE001 - reported in the log and the exit code
            if not STOP.is_set():
                # A session that cannot go on stops the whole bot (and the test that waits on it)
                # rather than leaving the server a silent session.
                self.error = f"{type(e).__name__}: {e}"
                log(self.args.log, event="bot-error", bot=self.bot_id, error=self.error)
                STOP.set()

    def _run(self):
        parent = self.args.instance
        self.session = self._call(
            self.stub.CreateBotSession,
            bots_pb2.CreateBotSessionRequest(
                parent=parent,
                bot_session=bots_pb2.BotSession(bot_id=self.bot_id, status=bots_pb2.OK, worker=self._worker()),
            ),
            POLL,
        )
        if self.session is None:
            return
        log(self.args.log, event="session", bot=self.bot_id, name=self.session.name)
        while not STOP.is_set() and self._remaining() > 0:
            # After a COMPLETED report BuildGrid's answer holds only the leases still to run (a
            # lease it retries comes back under the same id, and runs again).
            work = [l for l in self.session.leases if l.state in (bots_pb2.PENDING, bots_pb2.ACTIVE)]
            if not work:
                # Drop cancelled leases, then wait for work.
                del self.session.leases[:]
                if not self._update(min(POLL, max(self._remaining(), 0.5))):
                    break
                continue
            lease = work[0]
            if lease.state == bots_pb2.PENDING:
                lease.state = bots_pb2.ACTIVE
                if not self._update(POLL):
                    break
                continue
            self._run_lease(lease)
            # Report it (COMPLETED); BuildGrid may hand the next lease back in the same answer.
            if not self._update(min(POLL, max(self._remaining(), 0.5))):
                break

    def _run_lease(self, lease):
        start = time.monotonic()
        action = re_pb2.Action()
        if lease.payload.Is(re_pb2.Action.DESCRIPTOR):
            lease.payload.Unpack(action)
            action_digest = digest_of(action.SerializeToString())
        else:
            action_digest = re_pb2.Digest()
            lease.payload.Unpack(action_digest)
        last_tick = [time.monotonic()]

        def tick():
            # Keep-alive while the command runs: BuildGrid does not wait for work while this
            # session holds its one lease, so the update returns at once.
            if time.monotonic() - last_tick[0] < self.args.keepalive:
                return True
            last_tick[0] = time.monotonic()
            if not self._update(POLL):
                return False
            # BuildGrid drops a cancelled lease from the session.
            return any(l.id == lease.id for l in self.session.leases)

        status = status_pb2.Status(code=code_pb2.OK)
        result = None
        try:
            if not lease.payload.Is(re_pb2.Action.DESCRIPTOR):
                self.cas.read_message(action_digest, action)
            result = execute(self.cas, action, self.args.work, self.args.action_timeout, self.bot_id, tick)
        except LeaseEnd as e:
            status = status_pb2.Status(code=e.code, message=f"reapi-bot: {e}")
            self.failures += 1
        except (BotError, grpc.RpcError, OSError) as e:
            msg = e.details() if isinstance(e, grpc.RpcError) else str(e)
            status = status_pb2.Status(code=code_pb2.INTERNAL, message=f"reapi-bot: {msg}")
            self.failures += 1
        # Report: the lease in the session, COMPLETED, with the result.
        for l in self.session.leases:
            if l.id == lease.id:
                l.state = bots_pb2.COMPLETED
                l.status.CopyFrom(status)
                l.ClearField("result")
                if result is not None:
                    l.result.Pack(result)
        self.leases_done += 1
        log(
            self.args.log,
            event="completed",
            bot=self.bot_id,
            lease=lease.id,
            action=f"{action_digest.hash}/{action_digest.size_bytes}",
            exit_code=None if result is None else result.exit_code,
            status=code_pb2.Code.Name(status.code),
            message=status.message,
            outputs=0 if result is None else len(result.output_files) + len(result.output_directories),
            seconds=round(time.monotonic() - start, 3),
        )


def main():
    p = argparse.ArgumentParser(description="A Remote Workers API bot for BuildGrid (see the file's header).")
    p.add_argument("--server", required=True, help="HOST:PORT of the Bots, CAS and ByteStream services")
    p.add_argument("--instance", default="", help="REAPI instance name (default: the empty name)")
    p.add_argument("--workers", type=int, default=1, help="bot sessions, each running one action at a time")
    p.add_argument("--work", required=True, help="folder for input roots and the local blob cache")
    p.add_argument("--log", help="file to append one JSON line per lease to")
    p.add_argument("--deadline", type=float, required=True, help="stop after this many seconds")
    p.add_argument("--action-timeout", type=float, default=600, help="seconds, when the Action sets none")
    p.add_argument("--keepalive", type=float, default=30, help="seconds between keep-alives while a command runs")
    args = p.parse_args()
    if not (1 <= args.workers <= 64):
        p.error("--workers: 1 to 64")
    args.work = os.path.abspath(args.work)
    os.makedirs(args.work, exist_ok=True)
    args.deadline_at = time.monotonic() + args.deadline

    def on_signal(signum, _frame):
        STOP.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    options = [("grpc.max_receive_message_length", 64 << 20), ("grpc.max_send_message_length", 64 << 20)]
    channel = grpc.insecure_channel(args.server, options=options)
    try:
        grpc.channel_ready_future(channel).result(timeout=min(30, args.deadline))
    except grpc.FutureTimeoutError:
        log(args.log, event="error", error=f"no server at {args.server}")
        return 2
    cas = Cas(channel, args.instance, os.path.join(args.work, "blobs"))
    bots = [Bot(i, args, channel, cas) for i in range(args.workers)]
    for b in bots:
        b.start()
    while any(b.is_alive() for b in bots) and not STOP.is_set() and time.monotonic() < args.deadline_at:
        time.sleep(0.2)
    STOP.set()
    for b in bots:
        b.join(timeout=10)
    leases = sum(b.leases_done for b in bots)
    failures = sum(b.failures for b in bots)
    retries = sum(b.retries for b in bots)
    errors = [b.error for b in bots if b.error]
    log(args.log, event="stopped", leases=leases, failures=failures, retries=retries, errors=errors)
    channel.close()
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
