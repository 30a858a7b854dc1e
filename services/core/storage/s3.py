"""Objects in an S3 bucket (AWS, MinIO, moto); uploads as presigned multipart parts."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Literal

import boto3
from botocore.config import Config
from botocore.exceptions import BotoCoreError, ClientError
from botocore.exceptions import ConnectionError as BotoConnectionError

from services.core.storage import (
    READ_CHUNK,
    Disposition,
    MissingObjectError,
    StorageError,
    TransientStorageError,
    UploadedPart,
)


class S3Storage:
    """An S3 bucket (AWS, MinIO, moto) through boto3.

    Presigned URLs are signed for ``public_endpoint_url`` when it is set: inside docker
    compose the API reaches MinIO as ``http://minio:9000`` but the browser does not.
    """

    upload_mode: Literal["s3-multipart"] = "s3-multipart"

    def __init__(
        self,
        bucket: str,
        *,
        endpoint_url: str | None = None,
        public_endpoint_url: str | None = None,
        region: str = "us-east-1",
        access_key_id: str | None = None,
        secret_access_key: str | None = None,
    ) -> None:
        config = Config(
            signature_version="s3v4",
            s3={"addressing_style": "path"},
            retries={"mode": "standard", "max_attempts": 5},
            connect_timeout=10,
            read_timeout=60,
        )
        session = boto3.session.Session(
            aws_access_key_id=access_key_id,
            aws_secret_access_key=secret_access_key,
            region_name=region,
        )
        self.bucket = bucket
        self.client = session.client("s3", endpoint_url=endpoint_url, config=config)
        self.public_client = session.client(
            "s3", endpoint_url=public_endpoint_url or endpoint_url, config=config
        )

    @contextmanager
    def _errors(self, key: str) -> Iterator[None]:
        try:
            yield
        except ClientError as exc:
            error = exc.response.get("Error", {})
            code = str(error.get("Code", ""))
            status = int(exc.response.get("ResponseMetadata", {}).get("HTTPStatusCode", 0))
            if code in ("NoSuchKey", "404", "NotFound"):
                raise MissingObjectError(f"no object {key!r} in bucket {self.bucket}") from exc
            if status >= 500 or code in ("SlowDown", "RequestTimeout", "ServiceUnavailable"):
                raise TransientStorageError(f"S3 {code} on {key!r}: {exc}") from exc
            raise StorageError(f"S3 {code} on {key!r}: {error.get('Message', exc)}") from exc
        except BotoConnectionError as exc:
            raise TransientStorageError(f"S3 unreachable for {key!r}: {exc}") from exc
        except BotoCoreError as exc:
            raise StorageError(f"S3 error on {key!r}: {exc}") from exc

    def upload_file(self, path: Path, key: str, content_type: str) -> None:
        with self._errors(key):
            self.client.upload_file(
                str(path), self.bucket, key, ExtraArgs={"ContentType": content_type}
            )

    def download_file(self, key: str, path: Path) -> None:
        with self._errors(key):
            self.client.download_file(self.bucket, key, str(path))

    def read_bytes(self, key: str) -> bytes:
        with self._errors(key):
            return bytes(self.client.get_object(Bucket=self.bucket, Key=key)["Body"].read())

    def iter_bytes(self, key: str) -> Iterator[bytes]:
        with self._errors(key):
            body = self.client.get_object(Bucket=self.bucket, Key=key)["Body"]
            yield from body.iter_chunks(READ_CHUNK)

    def size(self, key: str) -> int | None:
        try:
            with self._errors(key):
                return int(self.client.head_object(Bucket=self.bucket, Key=key)["ContentLength"])
        except MissingObjectError:
            return None

    def list_keys(self, prefix: str) -> list[str]:
        with self._errors(prefix):
            pages = self.client.get_paginator("list_objects_v2").paginate(
                Bucket=self.bucket, Prefix=prefix
            )
            return sorted(obj["Key"] for page in pages for obj in page.get("Contents", []))

    def delete(self, key: str) -> None:
        with self._errors(key):
            self.client.delete_object(Bucket=self.bucket, Key=key)

    def download_url(
        self, key: str, expires_s: int, filename: str, disposition: Disposition
    ) -> str | None:
        params = {
            "Bucket": self.bucket,
            "Key": key,
            "ResponseContentDisposition": f'{disposition}; filename="{filename}"',
        }
        return str(
            self.public_client.generate_presigned_url(
                "get_object", Params=params, ExpiresIn=expires_s
            )
        )

    def check(self) -> None:
        with self._errors(""):
            self.client.head_bucket(Bucket=self.bucket)

    def create_multipart(self, key: str, content_type: str, checksums: bool) -> str:
        """Start a multipart upload; with `checksums`, S3 requires and checks a SHA-256
        per part and keeps the checksum of the part checksums for the object."""
        extra = {"ChecksumAlgorithm": "SHA256"} if checksums else {}
        with self._errors(key):
            response = self.client.create_multipart_upload(
                Bucket=self.bucket, Key=key, ContentType=content_type, **extra
            )
        return str(response["UploadId"])

    def presign_parts(
        self, key: str, upload_id: str, parts: dict[int, str | None], expires_s: int
    ) -> dict[int, str]:
        """PUT URLs for part numbers; a part's base64 SHA-256, if given, is signed into
        its URL (sent as ``x-amz-checksum-sha256``): S3 refuses a body that differs."""

        def sign(number: int, checksum: str | None) -> str:
            params: dict[str, object] = {
                "Bucket": self.bucket,
                "Key": key,
                "UploadId": upload_id,
                "PartNumber": number,
            }
            if checksum is not None:
                params["ChecksumSHA256"] = checksum
            return str(
                self.public_client.generate_presigned_url(
                    "upload_part", Params=params, ExpiresIn=expires_s
                )
            )

        return {number: sign(number, checksum) for number, checksum in parts.items()}

    def list_parts(self, key: str, upload_id: str) -> list[UploadedPart]:
        with self._errors(key):
            pages = self.client.get_paginator("list_parts").paginate(
                Bucket=self.bucket, Key=key, UploadId=upload_id
            )
            return [
                UploadedPart(int(p["PartNumber"]), int(p["Size"]), str(p["ETag"]))
                for page in pages
                for p in page.get("Parts", [])
            ]

    def complete_multipart(
        self,
        key: str,
        upload_id: str,
        parts: list[UploadedPart],
        checksums: dict[int, str] | None = None,
    ) -> None:
        """Assemble the parts; `checksums` (base64 SHA-256 by part) are checked by S3."""

        def entry(part: UploadedPart) -> dict[str, object]:
            fields: dict[str, object] = {"PartNumber": part.number, "ETag": part.etag}
            if checksums is not None:
                fields["ChecksumSHA256"] = checksums[part.number]
            return fields

        with self._errors(key):
            self.client.complete_multipart_upload(
                Bucket=self.bucket,
                Key=key,
                UploadId=upload_id,
                MultipartUpload={"Parts": [entry(p) for p in parts]},
            )

    def abort_multipart(self, key: str, upload_id: str) -> None:
        with self._errors(key):
            self.client.abort_multipart_upload(Bucket=self.bucket, Key=key, UploadId=upload_id)
